"""The Fast DDS profile every SoftSnap node loads: service replies that wait for new
clients, and participants announced every second so that late joiners find them soon.

No ROS imports: the test harness applies it before rclpy exists in its process.
"""
from __future__ import annotations

import os
from pathlib import Path

#: Fast DDS profile of every node (see the file's comment and use_node_profile).
NODE_PROFILE = Path(__file__).with_name('fastdds_profile.xml')
#: The reply writers' max_blocking_time in that profile (s); Fast DDS's default is 0.1 s.
SERVICE_REPLY_WAIT_S = 1.0
#: How often each node's participant announces itself in that profile (s); Fast DDS's
#: default is 3 s, which a process joining a running graph may wait out before it gets
#: a node's messages.
ANNOUNCEMENT_PERIOD_S = 1.0
#: Where Fast DDS finds a profiles file: 2.x (ROS 2 Jazzy) reads the first, 3.x (Kilted)
#: only the second. Both are set, each version reads its own; only Jazzy's runs here.
PROFILES_FILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def use_node_profile(environ=os.environ) -> Path | None:
    """Make this process's Fast DDS load NODE_PROFILE, unless the user chose.

    Call before ``rclpy.init``. Two reasons:

    - On a loaded computer a service server can receive a new client's request before it
      has discovered that client's reply reader; Fast DDS then waits 0.1 s and drops the
      reply, and the client never gets it (seen in CI: an action goal sent by a client
      that had just started never got its goal response). The profile makes that wait
      SERVICE_REPLY_WAIT_S.
    - A process joining a running graph often learns of a node only at the node's next
      periodic participant announcement (every 3 s by default): a recorder started into
      a running robot lost up to 3 s of some topics. The profile announces every
      ANNOUNCEMENT_PERIOD_S.

    Leaves `environ` alone (returns None) when another RMW than Fast DDS is selected, a
    profiles file is already set (the user's own file then decides) or the profile is
    missing from the install (Fast DDS would log an error for a file it cannot read).
    Returns the profile's path when it set it.
    """
    rmw = environ.get('RMW_IMPLEMENTATION', '')
    if ((rmw and not rmw.startswith('rmw_fastrtps'))
            or any(name in environ for name in PROFILES_FILE_VARIABLES)
            or not NODE_PROFILE.is_file()):
        return None
    for name in PROFILES_FILE_VARIABLES:
        environ[name] = str(NODE_PROFILE)
    return NODE_PROFILE
