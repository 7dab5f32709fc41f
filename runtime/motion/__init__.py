"""Robot and motion: the robot model and planning scene (``scene/``), joint states, trajectory
points and ``Samples``, the densified motion every motion behavior checks and sends.

Imports ``runtime.errors``, ``runtime.extras`` and ``runtime.io`` only (``tests/test_layers.py``)."""
