"""torchnav and ROS (docs/ros.md): episodes as ROS 2 bags (``bag``, through ``rosbags``), a policy run
open-loop on a recorded bag (``python -m torchnav.ros.replay_bag``), and two ROS 1 nodes (rospy): a policy
driving a robot (``python -m torchnav.ros.policy_node``) and a torchnav simulator standing in for one
(``python -m torchnav.ros.sim_node``).

Nothing is imported here: ``rosbags`` (``pip install torchnav[ros]``) and rospy (Debian's
``python3-rospy``, or a ROS 1 install) are imported by the modules that need them, when they are used.
The observation itself is built ROS-free by ``torchnav.observation``.
"""
