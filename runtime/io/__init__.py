"""Bus, ROS 2 and clocks: the ``Bus`` protocol and its in-process and rclpy bindings, the
simulated and wall clocks, timestamps, pacing and signals, and the project's ROS 2 interface
packages (``ros/interfaces/``).

Imports ``runtime.errors`` and ``runtime.extras`` only (``tests/test_layers.py``)."""
