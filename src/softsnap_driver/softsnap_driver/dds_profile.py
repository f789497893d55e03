"""The Fast DDS profile every SoftSnap node loads: service replies that wait for new clients.

No ROS imports: the test harness applies it before rclpy exists in its process.
"""
from __future__ import annotations

import os
from pathlib import Path

#: Fast DDS profile of every node: service replies wait up to SERVICE_REPLY_WAIT_S for a
#: new client to be discovered (see the file's comment and use_service_reply_profile).
SERVICE_REPLY_PROFILE = Path(__file__).with_name('fastdds_service_replies.xml')
#: The reply writers' max_blocking_time in that profile (s); Fast DDS's default is 0.1 s.
SERVICE_REPLY_WAIT_S = 1.0
#: Where Fast DDS finds a profiles file: 2.x (ROS 2 Jazzy) reads the first, 3.x (Kilted)
#: only the second. Both are set, each version reads its own; only Jazzy's runs here.
PROFILES_FILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def use_service_reply_profile(environ=os.environ) -> Path | None:
    """Make this process's Fast DDS load SERVICE_REPLY_PROFILE, unless the user chose.

    Call before ``rclpy.init``. On a loaded computer a service server can receive a new
    client's request before it has discovered that client's reply reader; Fast DDS then
    waits 0.1 s and drops the reply, and the client never gets it (seen in CI: an action
    goal sent by a client that had just started never got its goal response). The
    profile makes that wait SERVICE_REPLY_WAIT_S.

    Leaves `environ` alone (returns None) when another RMW than Fast DDS is selected, a
    profiles file is already set (the user's own file then decides) or the profile is
    missing from the install (Fast DDS would log an error for a file it cannot read).
    Returns the profile's path when it set it.
    """
    rmw = environ.get('RMW_IMPLEMENTATION', '')
    if ((rmw and not rmw.startswith('rmw_fastrtps'))
            or any(name in environ for name in PROFILES_FILE_VARIABLES)
            or not SERVICE_REPLY_PROFILE.is_file()):
        return None
    for name in PROFILES_FILE_VARIABLES:
        environ[name] = str(SERVICE_REPLY_PROFILE)
    return SERVICE_REPLY_PROFILE
