"""``objective smoke-test``: call a GetActionChunk service once, the way ExecutePolicy will, and judge it.

The guide's bring-up step 3: a throwaway client that catches nearly every wiring mistake in
seconds, before anything moves. It

1. takes the joints the policy commands, base to tip, from ``--joints`` or from the robot
   description (``--joint-group`` of ``--urdf``/``--srdf``), and appends the gripper joint last
   when one is given. It knows no robot of its own: it runs beside yours;
2. takes the positions from ``/joint_states`` (waits up to ``wait`` seconds, as ExecutePolicy
   does; a missing gripper joint there is a failure, as it is for ExecutePolicy). Decision: joint
   states are required, because a policy answering for a robot state nobody publishes proves
   little; ``--synthetic-joints`` sends zeros instead, for a server tested without a robot;
3. attaches one frame per camera topic, as captured (waits up to ``wait`` seconds each), or a
   gray 224 x 224 rgb8 frame per name with ``--synthetic-images``;
4. calls the service once with ``new_episode`` set (like ExecutePolicy's warmup call), bounded by
   ``timeout`` (ExecutePolicy's ``policy_call_timeout``, 3 s by default);
5. checks: status CHUNK_PRODUCED, step count (``--expected-steps``, else at least one), joint
   names equal to ``robot_state.name``, one finite position per joint in every point, and
   ``policy_action_chunk`` present and well laid out (steps first, ``data_offset`` 0, one row per
   step) when ``--rtc``; prints a verdict table. Exit 0 when every check passes, 1 otherwise.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from runtime.errors import OptionError

PASS, FAIL, INFO, SKIP = "PASS", "FAIL", "info", "skip"
SYNTHETIC_SIZE = 224


@dataclass(frozen=True)
class SmokeConfig:
    service_name: str
    joint_group: str | None = None
    """An SRDF group of ``urdf``/``srdf`` (base to tip); or name the joints in ``joints``."""
    joints: tuple[str, ...] = ()
    gripper_joint: str | None = None
    image_topics: tuple[str, ...] = ()
    image_names: tuple[str, ...] = ()
    prompt: str = ""
    rtc: bool = False
    expected_steps: int | None = None
    timeout: float = 3.0
    """Bound on the service call (ExecutePolicy's ``policy_call_timeout``)."""
    wait: float = 5.0
    """Bound on each wait for the service, the joint states and a frame per camera."""
    joint_states_topic: str = "/joint_states"
    synthetic_images: bool = False
    synthetic_joints: bool = False
    urdf: Path | None = None
    srdf: Path | None = None

    def __post_init__(self) -> None:
        if self.synthetic_images:
            if not self.image_names:
                raise OptionError("--synthetic-images needs --image-names (one frame per name)")
            if self.image_topics and len(self.image_topics) != len(self.image_names):
                raise OptionError(f"{len(self.image_topics)} image topics but {len(self.image_names)} image names")
        elif len(self.image_topics) != len(self.image_names):
            raise OptionError(
                f"{len(self.image_topics)} image topics but {len(self.image_names)} image names: "
                "the lists are index-aligned, one name per topic"
            )
        if len(set(self.image_names)) != len(self.image_names):
            raise OptionError(f"image names must be unique: {';'.join(self.image_names)}")
        if self.expected_steps is not None and self.expected_steps < 1:
            raise OptionError(f"--expected-steps must be at least 1, got {self.expected_steps}")
        if not self.timeout > 0 or not self.wait > 0:
            raise OptionError("--timeout and --wait must be positive")
        if (self.urdf is None) != (self.srdf is None):
            raise OptionError("--urdf and --srdf go together (the robot description --joint-group is read from)")
        if self.joints and (self.joint_group or self.urdf):
            raise OptionError("--joints names the joints itself: leave out --joint-group, --urdf and --srdf")
        if not self.joints and not (self.joint_group and self.urdf):
            raise OptionError("name the joints the policy commands, base to tip: --joints 'a;b;...', "
                             "or --joint-group NAME with the robot description --urdf FILE --srdf FILE")
        if len(set(self.joints)) != len(self.joints):
            raise OptionError(f"--joints names a joint twice: {';'.join(self.joints)}")


@dataclass
class Check:
    name: str
    result: str
    detail: str = ""


@dataclass
class SmokeReport:
    checks: list[Check] = field(default_factory=list)

    def add(self, name: str, result: str, detail: str = "") -> Check:
        check = Check(name, result, detail)
        self.checks.append(check)
        return check

    @property
    def passed(self) -> bool:
        return bool(self.checks) and all(c.result != FAIL for c in self.checks)

    def table(self) -> str:
        width = max([len("CHECK")] + [len(c.name) for c in self.checks])
        lines = [f"{'CHECK':<{width}}  RESULT  DETAIL"]
        lines += [f"{c.name:<{width}}  {c.result:<6}  {c.detail}" for c in self.checks]
        failed = sum(c.result == FAIL for c in self.checks)
        verdict = "PASS" if self.passed else f"FAIL ({failed} of {sum(c.result in (PASS, FAIL) for c in self.checks)} checks failed)"
        lines.append(f"VERDICT: {verdict}")
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Pure parts: the observation and the judgement
# --------------------------------------------------------------------------------------------
def observed_state(joint_state: Any, joints: Sequence[str], gripper: str | None) -> tuple[list[str], list[float]] | str:
    """``(names, positions)`` in ExecutePolicy's order from a JointState, or the problem."""
    index = {name: i for i, name in enumerate(joint_state.name)}
    wanted = list(joints) + ([gripper] if gripper else [])
    missing = [name for name in wanted if name not in index]
    if missing:
        return f"[{', '.join(missing)}] not in the joint states (they name [{', '.join(joint_state.name)}])"
    if len(joint_state.position) != len(joint_state.name):
        return f"{len(joint_state.name)} names but {len(joint_state.position)} positions"
    return wanted, [float(joint_state.position[index[name]]) for name in wanted]


def judge_response(report: SmokeReport, response: Any, names: Sequence[str], rtc: bool,
                   expected_steps: int | None) -> None:
    """Add the checks of one GetActionChunk response to ``report``."""
    from moveit_pro_ml_msgs.srv import GetActionChunk

    R = GetActionChunk.Response
    labels = {R.UNKNOWN: "UNKNOWN", R.CHUNK_PRODUCED: "CHUNK_PRODUCED", R.NO_MORE_ACTIONS: "NO_MORE_ACTIONS", R.ERROR: "ERROR"}
    status = labels.get(response.status, f"invalid ({response.status})")
    if response.status != R.CHUNK_PRODUCED:
        detail = f"{status}: {response.message}" if response.message else status
        report.add("status", FAIL, detail + ("" if response.status != R.UNKNOWN else " (the server never set a status)"))
        for name in ("step count", "joint names", "positions"):
            report.add(name, SKIP, "no chunk to check")
        return
    report.add("status", PASS, status + (f": {response.message}" if response.message else ""))

    points = list(response.chunk.points)
    steps = len(points)
    if steps == 0:
        report.add("step count", FAIL, "the chunk has no points")
    elif expected_steps is not None and steps != expected_steps:
        report.add("step count", FAIL, f"{steps} steps, expected {expected_steps}")
    else:
        report.add("step count", PASS, f"{steps} steps" + (" (as expected)" if expected_steps else ""))

    chunk_names = list(response.chunk.joint_names)
    if chunk_names == list(names):
        report.add("joint names", PASS, f"echo robot_state.name ({len(names)} joints)")
    else:
        report.add("joint names", FAIL, f"[{', '.join(chunk_names)}] differ from robot_state.name [{', '.join(names)}]")

    problem = None
    for step, point in enumerate(points):
        values = np.asarray(point.positions, dtype=float)
        if values.size != len(names):
            problem = f"step {step} has {values.size} positions for {len(names)} joints"
            break
        if not np.all(np.isfinite(values)):
            column = int(np.argmin(np.isfinite(values)))
            problem = f"step {step} joint '{names[column]}' is {values[column]}"
            break
    if problem:
        report.add("positions", FAIL, problem)
    elif points:
        report.add("positions", PASS, "every value finite, one per joint")

    period = float(response.native_control_period)
    report.add("control period", INFO, f"{period:g} s ({1 / period:g} Hz)" if period > 0 else "0 (no training rate reported)")

    policy = response.policy_action_chunk
    dims = [int(d.size) for d in policy.layout.dim]
    present = len(policy.data) > 0
    if not rtc:
        report.add("policy_action_chunk", INFO, f"{len(policy.data)} values (RTC off: not checked)" if present else "empty (RTC off)")
        return
    if not present:
        report.add("policy_action_chunk", FAIL, "empty, but RTC is on: the caller would send no carryover")
    elif policy.layout.data_offset != 0:
        report.add("policy_action_chunk", FAIL, f"data_offset is {policy.layout.data_offset}: the caller reads it as empty")
    elif not dims or dims[0] != steps or len(policy.data) % max(dims[0], 1) != 0:
        report.add("policy_action_chunk", FAIL, f"layout {dims} is not steps first with one row per step ({steps})")
    else:
        report.add("policy_action_chunk", PASS, f"{dims[0]} x {len(policy.data) // dims[0]}, steps first, data_offset 0")


# --------------------------------------------------------------------------------------------
# The run (ROS 2)
# --------------------------------------------------------------------------------------------
def group_joints(config: SmokeConfig) -> tuple[str, ...]:
    """The joints the policy commands, base to tip: ``--joints``, or the group of the robot
    description; ValueError naming the groups for an unknown one."""
    joints = config.joints
    if not joints:
        from runtime.motion.scene import GroupError, RobotModel

        try:
            assert config.urdf is not None and config.joint_group is not None  # SmokeConfig checks: a group of a description
            joints = tuple(RobotModel.from_urdf(config.urdf, config.srdf).group(config.joint_group).joints)
        except GroupError as exc:
            raise OptionError(str(exc)) from None
    if config.gripper_joint and config.gripper_joint in joints:
        where = f"the group '{config.joint_group}'" if config.joint_group else "--joints"
        raise OptionError(f"gripper joint '{config.gripper_joint}' is in {where}: it must be outside it")
    return joints


def _wait(condition: Callable[[], bool], seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


def run_smoke_test(config: SmokeConfig, bus: Any = None) -> SmokeReport:
    """Observe, call once, judge. ``bus`` defaults to a fresh ``RosBus`` (closed at the end)."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    from moveit_pro_ml_msgs.srv import GetActionChunk
    from sensor_msgs.msg import Image, JointState

    from .images import rgb_to_image

    joints = group_joints(config)
    report = SmokeReport()
    own_bus = bus is None
    if own_bus:
        from runtime.io.clock import WallClock
        from runtime.io.ros import RosBus

        bus = RosBus(WallClock(), node_name="policy_smoke_test")
    try:
        client = bus.create_client(config.service_name, GetActionChunk)
        joint_sub = None if config.synthetic_joints else bus.create_subscription(config.joint_states_topic, JointState, reliable=True)
        # Joint states reliable, as ExecutePolicy subscribes them; cameras best-effort, which matches
        # drivers publishing either (most use the best-effort sensor-data QoS).
        image_subs = [] if config.synthetic_images else [
            bus.create_subscription(t, Image, reliable=False) for t in config.image_topics]

        if _wait(client.service_is_ready, config.wait):
            report.add("service", PASS, f"{config.service_name} is available")
        else:
            report.add("service", FAIL, f"{config.service_name} did not appear within {config.wait:g} s (start the adapter first)")
            return report

        request = GetActionChunk.Request(prompt=config.prompt, new_episode=True)
        names = list(joints) + ([config.gripper_joint] if config.gripper_joint else [])
        if joint_sub is None:
            request.robot_state.name, request.robot_state.position = names, [0.0] * len(names)
            report.add("joint states", INFO, f"synthetic: zeros for {len(names)} joints")
        elif not _wait(lambda: joint_sub.latest is not None, config.wait):
            report.add("joint states", FAIL, f"nothing on {config.joint_states_topic} within {config.wait:g} s "
                       "(publisher running? it must be reliable QoS)")
            return report
        else:
            state = observed_state(joint_sub.latest, joints, config.gripper_joint)
            if isinstance(state, str):
                report.add("joint states", FAIL, f"{config.joint_states_topic}: {state}")
                return report
            request.robot_state.header = joint_sub.latest.header
            request.robot_state.name, request.robot_state.position = state
            report.add("joint states", PASS, f"{len(names)} joints from {config.joint_states_topic}: {', '.join(names)}")

        frames = []
        if config.synthetic_images:
            gray = np.full((SYNTHETIC_SIZE, SYNTHETIC_SIZE, 3), 128, dtype=np.uint8)
            frames = [rgb_to_image(gray) for _ in config.image_names]
            report.add("cameras", INFO, f"synthetic {SYNTHETIC_SIZE}x{SYNTHETIC_SIZE} gray rgb8 for {', '.join(config.image_names)}")
        else:
            for name, topic, sub in zip(config.image_names, config.image_topics, image_subs):
                if not _wait(lambda: sub.latest is not None, config.wait):
                    report.add(f"camera {name}", FAIL, f"no frame on {topic} within {config.wait:g} s (subscribed "
                               "best-effort, so a reliable or best-effort publisher matches: is the driver publishing?)")
                    return report
                frame = sub.latest
                frames.append(frame)
                report.add(f"camera {name}", PASS, f"{topic}: {frame.width}x{frame.height} {frame.encoding}")
        request.image_names = list(config.image_names)
        request.images = frames

        started = time.monotonic()
        future = client.call_async(request)
        if not _wait(future.done, config.timeout):
            future.cancel()
            report.add("call", FAIL, f"no answer within {config.timeout:g} s (ExecutePolicy's policy_call_timeout)")
            return report
        try:
            response = future.result()
        except Exception as exc:  # the transport failed; say so rather than crash
            report.add("call", FAIL, f"{type(exc).__name__}: {exc}")
            return report
        report.add("call", PASS, f"answered in {(time.monotonic() - started) * 1000:.1f} ms")
        judge_response(report, response, names, config.rtc, config.expected_steps)
        return report
    finally:
        if own_bus:
            bus.close()


def split_list(text: str | None) -> tuple[str, ...]:
    """``"a;b;c"`` -> ``("a", "b", "c")`` (BT.CPP's list syntax, as ExecutePolicy's ports use)."""
    return tuple(part.strip() for part in (text or "").split(";") if part.strip())
