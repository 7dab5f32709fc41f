"""The Objective server over ROS 2 (``objective server``) and its client (``objective client``)."""
