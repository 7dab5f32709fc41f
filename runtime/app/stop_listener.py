"""The protective stop of a process whose runs happen elsewhere (``objective eval``'s workers):
a node ``objective_eval`` that listens for the stop and the deadman (``runtime.app.protective_stop``)
and, when ``poll`` finds it engaged, forwards it through a ``SharedStop`` to every run.

The deadman is watched on the wall clock while ``poll`` is told runs are going: the operator's
heartbeat must arrive at least every ``deadman_period_s`` seconds of wall time then.
Discovery stays on this machine unless the environment opens it (``set_discovery_range``).
"""
from __future__ import annotations

import time

import rclpy
from rclpy.executors import SingleThreadedExecutor

from runtime.app.protective_stop import ProtectiveStop, SharedStop, StopInputs
from runtime.io.ros.bus import init_context, spin_on_thread
from runtime.io.ros.run import set_discovery_range

NODE_NAME = "objective_eval"


class StopListener:
    """The node, its spinning thread and the ``SharedStop`` it engages."""

    def __init__(self, inputs: StopInputs, shared: SharedStop, node_name: str = NODE_NAME) -> None:
        self.inputs, self.shared = inputs, shared
        set_discovery_range()
        self.context = init_context()
        self.node = rclpy.create_node(node_name, context=self.context)
        self.guard = ProtectiveStop(inputs)
        self.guard.serve_on_node(self.node)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._spinner = spin_on_thread(self.executor, node_name)

    def poll(self, running: bool) -> str | None:
        """Why the runs must stop (forwarded to them), or None. ``running``: runs are going now."""
        why = self.guard.reason(time.monotonic(), running)
        if why is not None:
            self.shared.engage(why)
        return why

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()
        self._spinner.join(timeout=2.0)
