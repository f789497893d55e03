"""Run the ring robot: ros2 launch softsnap_gaits ring.launch.py [simulate:=false] [gait:=...].

The graph (simulated modules, drivers, model, gait, rerun logger) comes from
softsnap_gaits.graph.robot_graph, the same description the demo runner uses.
"""
from softsnap_gaits.launching import generate_robot_launch_description


def generate_launch_description():
    return generate_robot_launch_description('ring')
