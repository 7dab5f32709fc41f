"""The policy side: what runs beside a robot, real or simulated, to answer GetActionChunk.

``backend`` (transport-free request/response and the ``PolicyBackend`` protocol), ``replay`` and
``lerobot_backend`` are backends; ``adapter`` and ``images`` convert to and from the ROS messages
(``node`` serves them on ROS 2); ``server``, ``wire`` and ``http_client`` are the HTTP inference
server, its JSON format and the adapter's client; ``smoke`` is the bring-up smoke test. Nothing
here imports the simulated cell (``tests/test_layers.py``): its oracle backend plugs in through
the ``objective.policy_backends`` entry-point group like any other.
"""
