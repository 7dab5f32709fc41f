"""Transport overhead: one GetActionChunk round trip carrying three 224x224 rgb8 images.

The policy does nothing (a fixed 50 x 7 chunk), so only the transport is measured:

- ``inprocess``: ``InProcessBus`` service call, the headless default (a function call);
- ``ros``: real ROS 2 on loopback: two ``runtime.io.ros.RosBus`` nodes in this process (Fast DDS,
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``), client polling the future as the runner does;
- ``http``: the HTTP adapter hop: an in-process GetActionChunk call served by
  ``PolicyAdapter(HttpBackend)`` (``policy/node.py``), which converts the messages and posts
  them as JSON to the inference server (``policy/server.py``) on 127.0.0.1;
- ``ros_http``: both hops, as the guide's deployment has them (ROS 2 call -> adapter -> HTTP).

Wall-clock milliseconds, p50 and p95 over the repeats (after warmup calls).

    .venv/bin/python benchmarks/bench_transport.py [--repeats N]
"""
from __future__ import annotations

import argparse
import time
import uuid
from typing import Any, Callable

import common  # noqa: F401  (environment and sys.path first)
from common import percentile, report, rounded

import numpy as np
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from runtime.io.bus import FixedLatency, InProcessBus
from runtime.io.clock import WallClock
from policy.backend import PolicyResponse
from policy.images import rgb_to_image

JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
          "robotiq_85_left_knuckle_joint"]
CAMERAS = ("scene", "wrist", "overview")
SIZE, STEPS = 224, 50


def make_request() -> Any:
    rng = np.random.default_rng(0)
    request = GetActionChunk.Request(prompt="stack the blue cube on the green cube", new_episode=False)
    request.robot_state = JointState(name=JOINTS, position=[0.1 * i for i in range(len(JOINTS))])
    request.image_names = list(CAMERAS)
    request.images = [rgb_to_image(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)) for _ in CAMERAS]
    return request


def fixed_response(request: Any) -> Any:
    """What a no-op policy answers: a 50-step chunk echoing the observed joints."""
    response = GetActionChunk.Response(status=GetActionChunk.Response.CHUNK_PRODUCED, native_control_period=0.1)
    start = list(request.robot_state.position)
    response.chunk = JointTrajectory(joint_names=list(request.robot_state.name),
                                     points=[JointTrajectoryPoint(positions=start) for _ in range(STEPS)])
    return response


class NoopBackend:
    """A ``PolicyBackend`` answering a fixed chunk at once (for the HTTP server)."""

    name = "noop"

    def load(self) -> None:
        pass

    def warmup(self, example_request: Any) -> None:
        pass

    def infer(self, request: Any) -> PolicyResponse:
        return PolicyResponse.chunk(np.tile(request.joint_positions, (STEPS, 1)), 0.1)


def round_trips(call: Callable[[], Any], repeats: int, warmup: int = 5) -> list[float]:
    """Milliseconds per call; each answer is checked so a broken path cannot look fast."""
    times = []
    for i in range(warmup + repeats):
        start = time.perf_counter()
        response = call()
        elapsed = (time.perf_counter() - start) * 1000.0
        if response.status != GetActionChunk.Response.CHUNK_PRODUCED or len(response.chunk.points) != STEPS:
            raise RuntimeError(f"the round trip answered status {response.status}: {response.message}")
        if i >= warmup:
            times.append(elapsed)
    return times


def poll(bus: Any, future: Any, timeout: float = 10.0) -> Any:
    """Wait for ``future`` like the runner does (spin, check), without its 10 ms tick."""
    deadline = time.perf_counter() + timeout
    while not future.done():
        if time.perf_counter() > deadline:
            raise TimeoutError("no answer within 10 s")
        bus.spin_once()
        time.sleep(0.0001)
    return future.result()


def inprocess_path(request: Any) -> Callable[[], Any]:
    bus = InProcessBus(WallClock())
    bus.create_service("/get_action_chunk", GetActionChunk, fixed_response)
    bus.set_latency("/get_action_chunk", FixedLatency(0.0))
    client = bus.create_client("/get_action_chunk", GetActionChunk)
    return lambda: poll(bus, client.call_async(request))


def ros_path(request: Any, handler: Callable[[Any], Any], closers: list[Callable[[], None]]) -> Callable[[], Any]:
    from runtime.io.ros import RosBus

    tag = uuid.uuid4().hex[:8]
    name = f"/bench_{tag}/get_action_chunk"
    server = RosBus(WallClock(), node_name=f"bench_policy_{tag}")
    client_bus = RosBus(WallClock(), node_name=f"bench_runtime_{tag}")
    closers.extend([server.close, client_bus.close])
    server.create_service(name, GetActionChunk, handler)
    client = client_bus.create_client(name, GetActionChunk)
    deadline = time.perf_counter() + 10.0
    while not client.service_is_ready():
        if time.perf_counter() > deadline:
            raise RuntimeError("the ROS 2 service was not discovered within 10 s")
        time.sleep(0.01)
    return lambda: poll(client_bus, client.call_async(request))


def http_adapter(closers: list[Callable[[], None]]) -> Any:
    """``PolicyAdapter(HttpBackend)`` in front of a started inference server; None when missing."""
    try:
        from policy.node import AdapterConfig, http_adapter as make_adapter
        from policy.server import InferenceServer, ServerConfig, WarmupSpec
    except ImportError:
        return None
    key = uuid.uuid4().hex
    server = InferenceServer(NoopBackend(), ServerConfig(key=key, warmup=WarmupSpec(images=tuple((c, SIZE, SIZE) for c in CAMERAS)))).start()
    closers.append(server.stop)
    if not server.ready.wait(10.0):
        raise RuntimeError("the inference server did not become ready within 10 s")
    return make_adapter(AdapterConfig(infer_url=f"{server.url}/infer", key=key, timeout=10.0))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()
    request = make_request()
    closers: list[Callable[[], None]] = []
    rows: list[dict[str, Any]] = []

    def measure(path: str, call: Callable[[], Any] | None, why: str = "") -> None:
        if call is None:
            rows.append({"bench": "transport", "path": path, "p50_ms": None, "p95_ms": None, "missing": why})
            return
        ms = round_trips(call, args.repeats)
        rows.append({"bench": "transport", "path": path, "p50_ms": rounded(percentile(ms, 50), 3),
                     "p95_ms": rounded(percentile(ms, 95), 3), "repeats": args.repeats})

    try:
        measure("inprocess", inprocess_path(request))
        measure("ros", ros_path(request, fixed_response, closers))
        adapter = http_adapter(closers)
        if adapter is None:
            why = "policy/server.py and policy/node.py are not importable"
            measure("http", None, why)
            measure("ros_http", None, why)
        else:
            bus = InProcessBus(WallClock())
            adapter.serve(bus, "/get_action_chunk")
            bus.set_latency("/get_action_chunk", FixedLatency(0.0))
            client = bus.create_client("/get_action_chunk", GetActionChunk)
            measure("http", lambda: poll(bus, client.call_async(request)))
            measure("ros_http", ros_path(request, adapter.handle, closers))
    finally:
        for close in reversed(closers):
            close()
    ratio = {r["path"]: r["p50_ms"] for r in rows}
    base = ratio.get("inprocess") or None
    for row in rows:
        row["p50_vs_inprocess"] = rounded(row["p50_ms"] / base, 1) if base and row["p50_ms"] is not None else None
    notes = [f"GetActionChunk with three {SIZE}x{SIZE} rgb8 images ({3 * SIZE * SIZE * 3 / 1e6:.2f} MB), a 50 x 7 chunk back; "
             f"{args.repeats} calls per path after 5 warmup calls; wall-clock ms"]
    report("bench_transport: GetActionChunk round trip", rows, ["path", "p50_ms", "p95_ms", "p50_vs_inprocess", "missing"], notes)


if __name__ == "__main__":
    main()
