"""Fault injection on the policy side: whatever the policy service does wrong, ExecutePolicy ends
with a clean stop (the arm at rest, no goal executing) and the right status and message, within
``policy_call_timeout`` of sim time.

Faults of the call itself (latency spikes, a dropped answer, malformed answers, a crashing
handler) are injected on the in-process bus; faults of the HTTP inference server (killed mid-run,
malformed JSON, 401, 503 while loading) go through the real adapter (``PolicyAdapter`` +
``HttpBackend``) to a real server on loopback.
"""
from __future__ import annotations

import http.server
import sys
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import pytest
from moveit_pro_ml_msgs.srv import GetActionChunk
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

import policy.node as node_mod
import policy.server as server_mod
from behaviors.execute_policy.chunk import MAX_CHUNK_STEPS
from runtime.io.bus import FixedLatency
from runtime.tree.loader import load_tree
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, make_context, run_tree
from sim.kinematic import KinematicWorld

R = GetActionChunk.Response
SERVICE = "/get_action_chunk"
TIMEOUT = 3.0
TICK = 0.01
BASE = f'total_action_steps="60" dt="0.1" committed_action_steps="20" goal_path_tolerance="0.3" policy_call_timeout="{TIMEOUT}"'
MOVE = np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0])  # rad/s of shoulder_pan: the arm is moving when faults hit


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def moving_chunk(request: Any, steps: int = 50, dt: float = 0.1) -> Any:
    start = np.array(request.robot_state.position)
    rate = np.append(MOVE, np.zeros(len(start) - len(MOVE)))
    rows = start + np.outer(np.arange(steps) * dt, rate)
    response = R(status=R.CHUNK_PRODUCED, native_control_period=dt)
    response.chunk = JointTrajectory(joint_names=list(request.robot_state.name),
                                     points=[JointTrajectoryPoint(positions=[float(v) for v in r]) for r in rows])
    return response


@dataclass
class Policy:
    """Answers good moving chunks, except call ``fault_at`` (0 = warmup), answered by ``fault``."""

    fault_at: int = -1
    fault: Callable[[Any], Any] | None = None
    calls: int = 0

    def __call__(self, request: Any) -> Any:
        index, self.calls = self.calls, self.calls + 1
        if index == self.fault_at and self.fault is not None:
            return self.fault(request)
        return moving_chunk(request)


class Latencies:
    """Latency per call index (0 = warmup); ``base`` for the others."""

    def __init__(self, base: float, **by_index: float) -> None:
        self.base, self.by_index, self.calls = base, {int(k[1:]): v for k, v in by_index.items()}, 0

    def delay(self, measured_wall_s: float) -> float:
        index, self.calls = self.calls, self.calls + 1
        return self.by_index.get(index, self.base)


@dataclass
class Outcome:
    status: str  # ExecutePolicy's own status
    message: str
    finished_at: float
    requested_at: list[float]
    world: KinematicWorld
    summary: dict[str, Any] = field(default_factory=dict)
    first_window_end: float = 0.0
    """Clock time at which the first executed chunk's window ends."""
    rejected: list[dict[str, Any]] = field(default_factory=list)
    """The data of each ``chunk_rejected`` event."""

    def assert_stopped_cleanly(self) -> None:
        controller = self.world.controllers["joint_trajectory_admittance_controller"]
        assert not controller.executing
        assert np.allclose(self.world.cell.arm_velocity_now, 0.0, atol=1e-9)


def run_with_faults(registry: Registry, handler: Callable[[Any], Any] | None, latency: Any,
                    before: Callable[[Any, KinematicWorld], None] | None = None, ports: str = "",
                    setup_error: bool = False, own_thread: bool = False) -> Outcome:
    """ExecutePolicy (``BASE`` and ``ports``) under ForceSuccess, then a 1 s Wait so the stop
    after a failure can be seen; with ``setup_error`` the run must end ERROR instead (no
    decorator catches a setup error); ``own_thread``: the handler is served as a policy adapter
    serves one (``create_service(own_thread=True)``)."""
    node = (f'<ExecutePolicy policy_service_name="{SERVICE}" joint_group_name="manipulator" {BASE} {ports} '
            'status_message="{message}"/>')
    xml = ('<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>'
           '<SwitchController activate_controllers="joint_trajectory_admittance_controller" deactivate_controllers="velocity_force_controller"/>'
           f'<ForceSuccess>{node}</ForceSuccess><Wait seconds="1.0"/></Sequence></BehaviorTree></root>')
    options = RunOptions(seed=0, max_seconds=60.0, world="kinematic")
    context = make_context(options)
    world = KinematicWorld({"seed": 0, "policy": "none"})
    loaded = load_tree(xml, registry, context)
    if handler is not None:
        context.bus.create_service(SERVICE, GetActionChunk, handler, own_thread=own_thread)
    if latency is not None:
        context.bus.set_latency(SERVICE, latency)
    if before is not None:
        before(context, world)
    result = run_tree(loaded, context, options, world=world)
    assert result.status == ("ERROR" if setup_error else "SUCCESS"), result.reason  # the Wait after ForceSuccess ran
    finished = context.events.of_kind("policy_finished")
    assert len(finished) == 1
    return Outcome(
        status=finished[0].data["status"],
        message=finished[0].data["message"],
        finished_at=finished[0].time,
        requested_at=[e.time for e in context.events.of_kind("chunk_requested")],
        world=world,
        summary=result.extra.get("execute_policy", {}),
        first_window_end=next((e.data["seam_time"] + e.data["steps"] * 0.1 for e in context.events.of_kind("chunk_executed")), 0.0),
        rejected=[e.data for e in context.events.of_kind("chunk_rejected")],
    )


# -- stale observations ----------------------------------------------------------------------
class Silent:
    """A publisher that has stopped."""

    def publish(self, msg: Any) -> None:
        pass


def publisher_stopping_at(topic: str, at_s: float, published: list[float]) -> Callable[[Any, KinematicWorld], None]:
    """``topic`` (the world's joint states, or a camera driver of the test's own publishing every
    tick) goes silent at ``at_s`` of clock time; ``published`` gets the time of each message."""
    from policy.images import rgb_to_image
    from sensor_msgs.msg import Image

    def before(context: Any, world: KinematicWorld) -> None:
        camera = None if topic == "/joint_states" else context.bus.create_publisher(topic, Image, reliable=False)
        frame = rgb_to_image(np.full((4, 6, 3), 200, np.uint8))
        step_to = world.step_to

        def step_then_publish(t: float) -> None:
            if t >= at_s - 1e-9 and camera is None:
                world.joint_states = Silent()
            step_to(t)
            if t < at_s - 1e-9:
                published.append(t)
                if camera is not None:
                    camera.publish(frame)

        world.step_to = step_then_publish

    return before


@pytest.mark.parametrize("topic, ports, limit_s", [
    ("/joint_states", "", 1.0),  # the default: 10 * dt
    ("/thermal_camera/color", 'image_topics="/thermal_camera/color" image_names="thermal" max_observation_age="0.8"', 0.8),
])
def test_a_publisher_that_stops_mid_run_stops_the_robot_naming_its_topic(registry, topic, ports, limit_s):
    """Its last message ages; the first request that would feed the policy one older than the
    bound stops the run (the arm at rest, no goal executing) instead."""
    published: list[float] = []
    out = run_with_faults(registry, Policy(), FixedLatency(0.1), publisher_stopping_at(topic, 2.5, published), ports)
    assert out.status == "FAILURE"
    age = out.finished_at - published[-1]
    assert age > limit_s and out.requested_at[-1] < 2.5 + limit_s  # the first request after it went stale
    assert out.message == (f"the newest message on '{topic}' is {age:.2f} s old, more than max_observation_age = "
                           f"{limit_s:.2f} s: its publisher stopped or fell behind; the policy is not fed an old world, "
                           "robot stopped")
    assert out.summary["oldest_observation_s"] == pytest.approx(age, abs=1e-4)
    out.assert_stopped_cleanly()


# -- latency ---------------------------------------------------------------------------------
def test_dropped_response_fails_at_policy_call_timeout_and_stops(registry):
    # Call 2 (the second real chunk) never answers: its future never completes.
    out = run_with_faults(registry, Policy(), Latencies(0.1, c2=float("inf")))
    assert out.status == "FAILURE"
    assert out.message == f"the policy service '{SERVICE}' did not answer within policy_call_timeout = {TIMEOUT:g} s"
    assert out.finished_at - out.requested_at[2] == pytest.approx(TIMEOUT, abs=2 * TICK)
    out.assert_stopped_cleanly()
    # After chunk 1's window the arm played its 26 steps beyond the window at full speed, then
    # slowed down (the tail's runout) and waited for chunk 2 until the timeout: the wait from the
    # end of full speed is a stall, counted although the wait ended in a failure.
    slowing_from = out.first_window_end + 2.6
    assert out.summary["stall_seconds"] == pytest.approx(out.finished_at - slowing_from, abs=1e-6)
    assert out.summary["stall_seconds"] > 0.1


def test_a_hung_in_process_policy_fails_at_policy_call_timeout_and_stops(registry):
    """On the simulated clock a handler's wall time is its latency: one still running after
    policy_call_timeout of wall time is not waited for longer, and the run fails as for an
    answer that never comes."""
    release, held = threading.Event(), []

    def hang(request: Any) -> Any:
        if not release.wait(20.0):  # bounded: the test releases it at the end
            held.append("the run waited for the hung policy past policy_call_timeout")
        return moving_chunk(request)

    try:
        out = run_with_faults(registry, Policy(fault_at=2, fault=hang), None, own_thread=True)
    finally:
        release.set()
    assert held == []
    assert out.status == "FAILURE"
    assert out.message == f"the policy service '{SERVICE}' did not answer within policy_call_timeout = {TIMEOUT:g} s"
    assert out.finished_at - out.requested_at[2] == pytest.approx(TIMEOUT, abs=2 * TICK)
    out.assert_stopped_cleanly()


def test_warmup_that_never_answers_fails_at_policy_call_timeout(registry):
    out = run_with_faults(registry, Policy(), Latencies(0.1, c0=float("inf")))
    assert out.status == "FAILURE"
    assert out.message.startswith(f"warming up the policy service '{SERVICE}' timed out after {TIMEOUT:g} s")
    assert out.finished_at - out.requested_at[0] == pytest.approx(TIMEOUT, abs=2 * TICK)
    out.assert_stopped_cleanly()


def test_latency_spike_beyond_the_timeout_fails_within_it(registry):
    out = run_with_faults(registry, Policy(), Latencies(0.1, c3=TIMEOUT + 0.5))
    assert out.status == "FAILURE" and "did not answer within policy_call_timeout" in out.message
    assert out.finished_at - out.requested_at[3] <= TIMEOUT + 2 * TICK
    out.assert_stopped_cleanly()


def test_latency_spike_beyond_the_window_pauses_then_finishes(registry):
    # The last chunk (call 3) takes 2.8 s (committed window 2 s, under the 3 s timeout). It was
    # asked for 0.2 s before chunk 2's window ends, and lands 2.6 s after that end. Meanwhile the
    # arm plays chunk 2's steps beyond its window up to the run's last-but-one step (16 at full
    # speed, then a 3-step runout), waits at rest from 1.6 s after the window's end until the
    # step after the chunk lands, and chunk 3 plays the last step.
    out = run_with_faults(registry, Policy(), Latencies(0.1, c3=2.8))
    assert out.status == "SUCCESS", out.message
    assert out.message == "executed 60 steps"
    assert out.summary["stall_seconds"] == pytest.approx(1.1, abs=0.01)
    out.assert_stopped_cleanly()


def test_run_continues_after_a_spike_in_the_middle(registry):
    out = run_with_faults(registry, Policy(), Latencies(0.1, c2=2.8))
    assert out.status == "SUCCESS", out.message


# -- malformed answers -----------------------------------------------------------------------
def _nan(request):
    response = moving_chunk(request)
    response.chunk.points[4].positions[2] = float("inf")
    return response


def _empty(request):
    response = moving_chunk(request)
    response.chunk.points = []
    return response


def _ragged(request):
    response = moving_chunk(request)
    response.chunk.points[7].positions = response.chunk.points[7].positions[:3]
    return response


def _renamed(request):
    response = moving_chunk(request)
    response.chunk.joint_names = ["joint_" + n for n in response.chunk.joint_names]
    return response


def _too_long(request):
    return moving_chunk(request, steps=MAX_CHUNK_STEPS + 1)


def _one_step(request):
    response = moving_chunk(request, steps=1)
    return response


def _status(value):
    def answer(request):
        response = moving_chunk(request)
        response.status = value
        return response

    return answer


def _raises(request):
    raise ConnectionResetError("adapter crashed")


def _exits(request):
    sys.exit(7)


def _keyboard_interrupt(request):
    raise KeyboardInterrupt


def _jump(request):
    response = moving_chunk(request)
    for point in response.chunk.points:
        point.positions = [p + 1.5 for p in point.positions]  # 1.5 rad away from where the arm is
    return response


@pytest.mark.parametrize(
    "fault, status, message",
    [
        (_nan, "FAILURE", "chunk 2 rejected: step 4 joint 'elbow_joint' is not finite (inf)"),
        (_empty, "FAILURE", "chunk 2 rejected: chunk has no points"),
        (_ragged, "FAILURE", "chunk 2 rejected: step 7 has 3 positions for 6 joint names"),
        (_renamed, "FAILURE", "chunk 2 rejected: joint names do not match the joint group"),
        (_one_step, "FAILURE", "chunk 2 rejected: chunk 2 has 1 steps but takes over at its step"),
        (_too_long, "FAILURE", f"chunk 2 rejected: chunk has {MAX_CHUNK_STEPS + 1} points, more than the {MAX_CHUNK_STEPS} one chunk may carry"),
        (_status(R.UNKNOWN), "FAILURE", "the policy answered UNKNOWN for the chunk 2"),
        (_status(R.ERROR), "FAILURE", "the policy answered ERROR for the chunk 2"),
        (_status(42), "FAILURE", "the policy answered status 42 for the chunk 2"),
        (_status(R.NO_MORE_ACTIONS), "SUCCESS", "the policy has no more actions"),
        (_raises, "FAILURE", f"calling the policy service '{SERVICE}' failed: adapter crashed"),
        (_exits, "FAILURE", f"calling the policy service '{SERVICE}' failed: its handler raised SystemExit: 7"),
        (_keyboard_interrupt, "FAILURE", f"calling the policy service '{SERVICE}' failed: its handler raised KeyboardInterrupt"),
        (_jump, "FAILURE", "chunk 2 rejected: densified step"),
    ],
    ids=["inf", "empty", "ragged", "renamed", "one-step", "too-long", "unknown", "error", "status-42", "no-more-actions", "raises", "exits",
         "keyboard-interrupt", "jump"],
)
def test_malformed_answer_stops_the_arm_with_the_reason(registry, fault, status, message):
    out = run_with_faults(registry, Policy(fault_at=2, fault=fault), FixedLatency(0.1))
    assert out.status == status, out.message
    assert out.message.startswith(message), out.message
    # Decided when the answer lands, one tick after it is due.
    assert out.finished_at - out.requested_at[2] == pytest.approx(0.1, abs=2 * TICK)
    out.assert_stopped_cleanly()


def _with_policy_chunk(data: list[float], sizes: list[int], offset: int = 0) -> Callable[[Any], Any]:
    def answer(request):
        response = moving_chunk(request)
        response.policy_action_chunk = Float64MultiArray(data=data)
        response.policy_action_chunk.layout.dim = [MultiArrayDimension(size=n) for n in sizes]
        response.policy_action_chunk.layout.data_offset = offset
        return response

    return answer


def _with_period(period: float) -> Callable[[Any], Any]:
    def answer(request):
        response = moving_chunk(request)
        response.native_control_period = period
        return response

    return answer


RTC = 'policy_uses_real_time_chunking="true"'
LAY_OUT = "lay it out as (steps, action dims), steps first, with data_offset 0"


@pytest.mark.parametrize("fault, ports, message", [
    # on main each was taken in silence: NaN went back to the policy as its previous chunk, the
    # others turned the carryover off or were ignored
    (_with_policy_chunk([0.0, float("nan"), 0.0, 0.0], [2, 2]), RTC,
     "chunk 2 rejected: policy_action_chunk step 0 dim 1 is not finite (nan)"),
    (_with_policy_chunk([0.0] * 4, [2, 2], offset=1), RTC, f"chunk 2 rejected: policy_action_chunk has data_offset 1: {LAY_OUT}"),
    (_with_policy_chunk([0.0] * 4, [3, 2]), RTC,
     f"chunk 2 rejected: policy_action_chunk has 4 values but its layout gives sizes [3, 2]: {LAY_OUT}"),
    (_with_policy_chunk([0.0] * 4, []), RTC, f"chunk 2 rejected: policy_action_chunk has 4 values but its layout gives sizes []: {LAY_OUT}"),
    (_with_period(-0.1), "", "chunk 2 rejected: native_control_period is -0.1 s: answer the seconds per step the policy was "
                             "trained at, or 0 when it has no training rate"),
    (_with_period(float("nan")), "", "chunk 2 rejected: native_control_period is nan s"),
], ids=["nan-policy-chunk", "offset", "sizes", "no-dims", "negative-period", "nan-period"])
def test_a_malformed_rtc_echo_or_period_stops_the_arm_with_the_reason(registry, fault, ports, message):
    out = run_with_faults(registry, Policy(fault_at=2, fault=fault), FixedLatency(0.1), ports=ports)
    assert out.status == "FAILURE"
    assert out.message.startswith(message), out.message
    out.assert_stopped_cleanly()


def test_rtc_without_a_policy_action_chunk_warns_once(registry):
    out = run_with_faults(registry, Policy(), FixedLatency(0.1), ports=RTC)
    assert out.status == "SUCCESS", out.message
    assert [w for w in out.summary["warnings"] if "policy_action_chunk" in w] == [
        "policy_uses_real_time_chunking is true but chunk 1 carries no policy_action_chunk: the policy gets no "
        "previous_action_chunk back, so real-time chunking does nothing (send it, or set policy_uses_real_time_chunking=\"false\" "
        "for a policy without a denoising loop)"
    ]


@pytest.mark.parametrize("offset_rad, warned", [(0.3, True), (0.15, False)])
def test_a_first_chunk_far_from_the_arm_warns_naming_the_joint(registry, offset_rad, warned):
    """0.3 rad of the base joint (within the cell's envelope: the tool turns about the base,
    still pointing down) was blended in without a word."""
    def far(request):
        response = moving_chunk(request)
        for point in response.chunk.points:
            point.positions = [p - offset_rad * (j == 0) for j, p in enumerate(point.positions)]
        return response

    out = run_with_faults(registry, Policy(fault_at=1, fault=far), FixedLatency(0.1))
    assert out.status == "SUCCESS", out.message
    expected = [f"chunk 1 starts {offset_rad:.3f} rad from where the arm was at its request (joint shoulder_pan_joint; more than "
                "0.2 rad): it is blended in, but check the policy's joint order, units and the state it was given"]
    assert [w for w in out.summary["warnings"] if w.startswith("chunk 1 starts")] == (expected if warned else [])


def test_a_chunk_a_million_radians_away_is_reported_by_the_value_the_policy_sent(registry):
    """The rejection names the policy's own value, its step and joint, before anything is shaped
    or sent (not the first densified point, a value the blend makes up far from what was sent)."""
    sent: list[float] = []

    def far(request):
        response = moving_chunk(request)
        for point in response.chunk.points:
            point.positions = [p + 1e6 for p in point.positions]
        sent.append(response.chunk.points[0].positions[0])
        return response

    out = run_with_faults(registry, Policy(fault_at=2, fault=far), FixedLatency(0.1))
    assert out.status == "FAILURE"
    # Chunk 1 arrives on run step 1 and its window starts there (steps 1 to 21); chunk 2 is asked
    # for two steps before that window ends, at step 19, so its step 0 is policy step 19.
    assert out.message == (f"chunk 2 rejected: step 0: joint shoulder_pan_joint position {sent[0]:.4f} rad exceeds the "
                           "limit 6.2832 rad (policy step 19 of the run)")
    out.assert_stopped_cleanly()
    # the event carries the rejected chunk for the report to plot, on the clock from its request step
    (rejected,) = out.rejected
    assert rejected["joints"][0] == "shoulder_pan_joint" and rejected["positions"][0][0] == pytest.approx(sent[0])
    assert np.diff(rejected["times"]) == pytest.approx(np.full(len(rejected["times"]) - 1, 0.1))
    assert rejected["times"][0] < out.finished_at  # its step 0 was due before the run stopped on it


# -- the HTTP inference server behind the adapter --------------------------------------------


class ChunkBackend:
    """A backend answering moving chunks; ``load`` waits for ``release`` (to hold the server in loading)."""

    name = "faulty"

    def __init__(self, release: threading.Event | None = None) -> None:
        self.release = release

    def load(self) -> None:
        if self.release is not None:
            self.release.wait(30.0)

    def warmup(self, example_request: Any) -> None:
        pass

    def infer(self, request: Any) -> Any:
        from policy.backend import PolicyResponse

        rate = np.append(MOVE, np.zeros(len(request.joint_positions) - len(MOVE)))
        return PolicyResponse.chunk(request.joint_positions + np.outer(np.arange(50) * 0.1, rate), 0.1)


@pytest.fixture
def servers():
    started: list[Any] = []

    def start(backend: Any, key: str = "right-key", wait: bool = True) -> Any:
        server = server_mod.InferenceServer(backend, server_mod.ServerConfig(key=key)).start()
        started.append(server)
        if wait:
            assert server.ready.wait(10.0)
        return server

    yield start
    for server in started:
        server.stop()


def serve_adapter(url: str, key: str = "right-key") -> Callable[[Any, KinematicWorld], None]:
    def install(context: Any, world: KinematicWorld) -> None:
        adapter = node_mod.http_adapter(node_mod.AdapterConfig(infer_url=url, key=key, timeout=TIMEOUT))
        adapter.serve(context.bus, SERVICE)
        context.bus.set_latency(SERVICE, FixedLatency(0.1))  # sim-time latency; the HTTP hop is real

    return install


def test_server_killed_mid_run_fails_with_the_adapter_reason(registry, servers):
    server = servers(ChunkBackend())
    base = server.url
    url = f"{base}/infer"

    def kill_after_first_chunk(context, world):
        serve_adapter(url)(context, world)
        step_to = world.step_to

        def step(t):
            step_to(t)
            if t >= 1.0 and server._httpd is not None:
                server.stop()

        world.step_to = step

    out = run_with_faults(registry, None, None, before=kill_after_first_chunk)
    assert out.status == "FAILURE"
    assert out.message.startswith(f"the policy answered ERROR for the chunk 2: cannot reach the inference server at {base}")
    out.assert_stopped_cleanly()


def test_wrong_key_is_a_401_error_at_the_warmup(registry, servers):
    server = servers(ChunkBackend())
    out = run_with_faults(registry, None, None, before=serve_adapter(f"{server.url}/infer", key="wrong-key"), setup_error=True)
    assert out.status == "ERROR"
    assert out.message.startswith(f"the policy answered ERROR for the warmup: the inference server at {server.url}")
    assert "answered 401" in out.message
    out.assert_stopped_cleanly()


def test_server_still_loading_answers_503_and_the_run_fails_cleanly(registry, servers):
    release = threading.Event()
    server = servers(ChunkBackend(release), wait=False)
    try:
        out = run_with_faults(registry, None, None, before=serve_adapter(f"{server.url}/infer"), setup_error=True)
    finally:
        release.set()
    assert out.status == "ERROR"
    assert "answered 503" in out.message and "still loading" in out.message
    out.assert_stopped_cleanly()


class _MalformedJson(http.server.BaseHTTPRequestHandler):
    def do_POST(self) -> None:  # noqa: N802
        self.rfile.read(int(self.headers.get("Content-Length", 0)))
        body = b'{"status": "chunk", "actions": [[0.1, 0.2], [0.3'  # cut off mid-array
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args: Any) -> None:
        pass


def test_malformed_json_from_the_server_is_an_error_with_the_reason(registry):
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _MalformedJson)
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{httpd.server_address[1]}"
        out = run_with_faults(registry, None, None, before=serve_adapter(f"{url}/infer"), setup_error=True)
    finally:
        httpd.shutdown()
        httpd.server_close()
    assert out.status == "ERROR"
    assert out.message.startswith(f"the policy answered ERROR for the warmup: the inference server at {url}/infer sent a malformed answer: response body is not valid JSON")
    out.assert_stopped_cleanly()


def test_a_step_period_that_changes_after_the_first_chunk_is_warned_once(registry):
    """Chunk 2 says 0.05 s per step after chunk 1's 0.1 s: on main nothing was said."""
    out = run_with_faults(registry, Policy(fault_at=2, fault=_with_period(0.05)), FixedLatency(0.1))
    assert out.status == "SUCCESS", out.message
    assert [w for w in out.summary["warnings"] if "steps every" in w] == [
        "chunk 2 says the policy steps every 0.05 s, but the first chunk said 0.1 s: every chunk is played at "
        "dt = 0.1 s per step (not retimed)"
    ]
