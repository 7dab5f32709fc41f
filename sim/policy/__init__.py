"""The policy side of the worked example: backends (oracle, replay) and the GetActionChunk adapter.

``backend`` (transport-free request/response and the ``PolicyBackend`` protocol) and ``oracle``
(apart from ``SceneKinematics``) import no ROS, so the HTTP inference server can reuse them;
``adapter`` and ``images`` convert to and from the ROS messages.
"""
