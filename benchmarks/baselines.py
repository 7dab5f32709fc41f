"""Two baseline chunk executors, and the task policy they are compared on (``benchmarks/bench_streaming.py``).

What is compared is the *commanded joint stream*: the setpoint each executor sends the arm at
every policy tick (``dt``). The baselines are pure simulations of that stream on the sim clock
(no controller, no physics): the arm is taken to be exactly where it is commanded, which is what
the kinematic world does for ExecutePolicy too. Both baselines get the same policy answers (the
same chunk for the same call index and observed state) and the same latency trace (call ``i``
takes ``trace[i]`` seconds) as ExecutePolicy does in the benchmark.

- ``run_sync``: stop, infer, execute the chunk, repeat. The arm holds its last setpoint while a
  call is in flight, then plays chunk steps ``1 .. committed`` at one per tick (step 0 is the
  observed state) and asks again.
- ``run_lerobot_aggregate``: LeRobot's async robot client (``lerobot.async_inference``): a queue
  of timestamped actions; an observation is sent (one call in flight at a time) whenever
  ``len(queue) / chunk_size <= threshold`` (0.5); an arriving chunk's actions whose timestep has
  already been played are dropped, those already queued are aggregated ``0.3 * old + 0.7 * new``
  (LeRobot's ``weighted_average``), the rest are appended; one action is played per tick with no
  smoothing, and the arm holds when the queue is empty. Where lerobot is installed (``make
  lerobot``) the queue is LeRobot's own code (``LeRobotQueue``: ``RobotClient``'s
  ``_aggregate_action_queues`` and ``_ready_to_send_observation``); without it, a reimplementation
  (``ReimplementedQueue``). The stream says which ran.

- ``run_jtc_newest_wins``: ros2_controllers' way (a VLA streamer publishing positions-only chunks
  to a ``joint_trajectory_controller`` with ``positions_upsampling``, ros2_controllers #2491, as
  ros2_control_demos' example_19 does): an observation every ``request_every`` ticks (the committed
  window of the others), one call in flight; each arriving chunk wins at once. Its
  points are timed ``(i + 1) * dt`` from the arrival, joined by the C2 cubic spline through them
  whose start velocity is clamped to the last command (the follow-up to #2491; #2491 itself starts
  at rest) and which ends at rest, and merged into the playing trajectory at arrival (#2419: a
  bridge point from the old spline, then the new points). No limit or collision check. The
  controller is the simulated cell's JTC model (``sim.controllers.jtc_trajectory``).

``TaskPolicy`` answers with chunks of a smooth task path, starting from where the observed state
lies on the path (like a real policy, it sees only the observation), with realistic
chunk-to-chunk disagreement: a per-chunk phase offset, a per-chunk position offset and small
per-step jitter, seeded by the call index so every executor sees the same disagreement.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from sim.controllers.jtc_trajectory import JtcPoints, JtcTrajectory, merge_at_arrival


# --------------------------------------------------------------------------------------------
# The task and the policy
# --------------------------------------------------------------------------------------------
class ChunkSource(Protocol):
    """What the streaming baselines ask for chunks: a ``TaskPolicy``, or a ``GlitchingPolicy`` around one."""

    @property
    def chunk_steps(self) -> int: ...

    def reset(self) -> None: ...

    def chunk(self, index: int, observed: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class TaskPath:
    """``q(s) = start + sum_m amplitude[m] * (1 - cos(m * pi * s / duration))`` for s in [0, duration].

    Every term has zero velocity at both ends, so the task starts and ends at rest; outside
    ``[0, duration]`` the path holds its end points.
    """

    start: np.ndarray
    amplitudes: np.ndarray  # (harmonics, joints); row m-1 multiplies harmonic m
    duration: float

    def at(self, s: np.ndarray | float) -> np.ndarray:
        along = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, self.duration)
        m = np.arange(1, len(self.amplitudes) + 1)[None, :]
        basis = 1.0 - np.cos(m * math.pi * along[:, None] / self.duration)  # (N, harmonics)
        return self.start[None, :] + basis @ self.amplitudes

    @property
    def goal(self) -> np.ndarray:
        return self.at(self.duration)[0]


@dataclass
class TaskPolicy:
    """Chunks of ``path`` from the observed state's place on it, with per-chunk disagreement.

    The place on the path is found by projecting the observation onto the path near where the
    previous call found it (a policy knows roughly where it is in its task). Disagreement for
    call ``index``: the chunk plays the path shifted by a phase offset ~ N(0, ``phase_sd``) s,
    plus a constant offset ~ N(0, ``offset_sd``) rad per joint, plus white jitter
    ~ N(0, ``jitter_sd``) rad per step and joint. Step 0 of a chunk is the request instant.
    """

    path: TaskPath
    dt: float
    chunk_steps: int = 50
    phase_sd: float = 0.03
    offset_sd: float = 0.003
    jitter_sd: float = 0.0005
    seed: int = 0
    _phase: float = field(default=0.0, init=False)
    _grid: np.ndarray = field(init=False, repr=False)
    _points: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._grid = np.arange(0.0, self.path.duration + 1e-9, 0.002)
        self._points = self.path.at(self._grid)

    def reset(self) -> None:
        self._phase = 0.0

    def phase_of(self, observed: np.ndarray) -> float:
        """Where on the path ``observed`` lies, searched from 0.5 s before the last answer on."""
        window = (self._grid >= self._phase - 0.5) & (self._grid <= self._phase + 8.0)
        idx = np.flatnonzero(window)
        dist = np.abs(self._points[idx] - np.asarray(observed)[None, :]).max(axis=1)
        return float(self._grid[idx[int(np.argmin(dist))]])

    def chunk(self, index: int, observed: np.ndarray) -> np.ndarray:
        """The (chunk_steps, joints) answer to call ``index`` observing ``observed``."""
        self._phase = self.phase_of(observed)
        rng = np.random.default_rng([self.seed, index])
        joints: int = self.path.start.shape[0]
        shift = rng.normal(0.0, self.phase_sd)
        offset = rng.normal(0.0, self.offset_sd, joints)
        jitter = rng.normal(0.0, self.jitter_sd, (self.chunk_steps, joints))
        times = self._phase + shift + np.arange(self.chunk_steps) * self.dt
        return self.path.at(times) + offset[None, :] + jitter


def benchmark_task(start: np.ndarray, duration: float = 10.0) -> TaskPath:
    """The benchmark's task: a 10 s sweep from ``start`` (up to about 0.8 rad per joint, peak
    joint speed about 0.24 rad/s), collision-free in the cell from the Ready waypoint."""
    amplitudes = np.array(
        [
            [0.40, -0.20, 0.30, -0.20, 0.30, 0.40],  # harmonic 1: out to the far end
            [0.16, 0.08, -0.12, 0.12, -0.10, 0.20],  # harmonic 2: a return bend
            [0.06, -0.04, 0.04, -0.06, 0.06, -0.08],  # harmonic 3: a wiggle
        ]
    )
    return TaskPath(np.asarray(start, dtype=float), amplitudes, duration)


# --------------------------------------------------------------------------------------------
# The executors' output
# --------------------------------------------------------------------------------------------
@dataclass
class Stream:
    """A commanded joint stream sampled every ``dt`` from the first request (t = 0)."""

    dt: float
    positions: np.ndarray  # (ticks, joints): the setpoint at tick k, time k * dt
    seams: list[int]  # ticks whose setpoint is the first one taken from a newly arrived chunk
    calls: int
    implementation: str = ""  # which code produced it, where that differs (LeRobot's own or a reimplementation)

    @property
    def times(self) -> np.ndarray:
        return np.arange(len(self.positions)) * self.dt


def run_sync(policy: ChunkSource, trace: list[float], start: np.ndarray, dt: float, committed: int, total_steps: int) -> Stream:
    """Stop, infer, execute ``committed`` steps of the chunk, repeat, until ``total_steps`` played."""
    policy.reset()
    q = np.asarray(start, dtype=float).copy()
    out, seams = [q.copy()], []
    played = call = 0
    while played < total_steps:
        latency = trace[call % len(trace)]
        chunk = policy.chunk(call, q)
        call += 1
        wait_ticks = math.ceil(latency / dt - 1e-9)
        if wait_ticks and played:
            seams.append(len(out))  # the stop at the end of the previous chunk is a seam too
        out.extend(q.copy() for _ in range(wait_ticks))  # holding still while the call is in flight
        steps = min(committed, total_steps - played, len(chunk) - 1)
        seams.append(len(out))
        for row in chunk[1 : steps + 1]:
            out.append(row.copy())
        q = out[-1].copy()
        played += steps
    return Stream(dt, np.array(out), seams, call)


class ReimplementedQueue:
    """LeRobot's client-side action queue, reimplemented (for installations without LeRobot):
    timestep -> action; an arriving action already played is dropped, one already queued is
    aggregated ``old_weight * old + (1 - old_weight) * new``, the rest are appended."""

    implementation = "reimplementation (lerobot not installed)"

    def __init__(self, old_weight: float = 0.3) -> None:
        self.old_weight = old_weight
        self.queue: dict[int, np.ndarray] = {}  # in timestep order
        self.latest_action = -1  # timestep of the last played action

    def __len__(self) -> int:
        return len(self.queue)

    def merge(self, first_timestep: int, actions: np.ndarray) -> None:
        merged: dict[int, np.ndarray] = {}
        for i, action in enumerate(actions):
            step = first_timestep + i
            if step <= self.latest_action:
                continue
            merged[step] = self.old_weight * self.queue[step] + (1.0 - self.old_weight) * action if step in self.queue else action
        self.queue = merged

    def ready(self, chunk_steps: int, threshold: float) -> bool:
        return len(self.queue) / chunk_steps <= threshold

    def pending(self) -> list[np.ndarray]:
        """The queued actions in the order they will be played."""
        return [self.queue[step] for step in sorted(self.queue)]

    def pop(self) -> np.ndarray:
        step = min(self.queue)
        self.latest_action = step
        return self.queue.pop(step)


class LeRobotQueue:
    """LeRobot's own client-side action queue: the queue state of ``lerobot.async_inference``'s
    ``RobotClient`` (a ``Queue`` of ``TimedAction``, its locks, ``latest_action``), driven by
    that class's own methods: ``_aggregate_action_queues`` with the ``weighted_average``
    aggregate function merges a chunk, ``_ready_to_send_observation`` decides when to send an
    observation. Only the parts of ``RobotClient`` that need a robot and a server are left out
    (its constructor, the gRPC threads); a popped action sets ``latest_action`` as its control
    loop does."""

    implementation = "lerobot (RobotClient._aggregate_action_queues, weighted_average)"

    def __init__(self, chunk_size_threshold: float = 0.5, aggregate_fn_name: str = "weighted_average") -> None:
        import threading
        from queue import Queue

        from policy.lerobot_offline import force_offline

        force_offline()
        from lerobot.async_inference.configs import get_aggregate_function

        self._client = _import_robot_client()
        self.aggregate_fn = get_aggregate_function(aggregate_fn_name)
        self.action_queue: Queue = Queue()
        self.action_queue_lock = threading.Lock()
        self.latest_action_lock = threading.Lock()
        self.latest_action = -1
        self.action_chunk_size = -1
        self._chunk_size_threshold = chunk_size_threshold

    def __len__(self) -> int:
        return self.action_queue.qsize()

    def merge(self, first_timestep: int, actions: np.ndarray) -> None:
        import torch
        from lerobot.async_inference.helpers import TimedAction

        self.action_chunk_size = max(self.action_chunk_size, len(actions))  # as its receive thread does
        timed = [TimedAction(timestamp=0.0, timestep=first_timestep + i, action=torch.from_numpy(np.array(a))) for i, a in enumerate(actions)]
        self._client._aggregate_action_queues(self, timed, self.aggregate_fn)

    def ready(self, chunk_steps: int, threshold: float) -> bool:
        assert threshold == self._chunk_size_threshold, "the threshold is the client's configuration"
        return self._client._ready_to_send_observation(self)

    def pending(self) -> list[np.ndarray]:
        """The queued actions in the order they will be played (the queue is left as it is)."""
        return [timed.get_action().numpy() for timed in list(self.action_queue.queue)]

    def pop(self) -> np.ndarray:
        timed = self.action_queue.get_nowait()
        self.latest_action = timed.get_timestep()
        return timed.get_action().numpy()


def _import_robot_client() -> type[Any]:
    """``lerobot.async_inference.robot_client.RobotClient``. Defining the class sets up its
    logger, which writes ``logs/robot_client_<time>.log`` under the working directory and
    reconfigures the root logger: it is imported from a scratch directory, and the root
    logger's handlers and level are put back."""
    import contextlib
    import logging
    import sys
    import tempfile

    if "lerobot.async_inference.robot_client" in sys.modules:
        return sys.modules["lerobot.async_inference.robot_client"].RobotClient
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        with tempfile.TemporaryDirectory() as scratch, contextlib.chdir(scratch):
            from lerobot.async_inference.robot_client import RobotClient
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)
    return RobotClient


def lerobot_queue_or_reimplementation(threshold: float = 0.5) -> LeRobotQueue | ReimplementedQueue:
    """LeRobot's own queue where ``lerobot`` (with its async-inference extra) is installed, else
    the reimplementation; ``.implementation`` says which."""
    try:
        return LeRobotQueue(chunk_size_threshold=threshold)
    except ImportError:
        return ReimplementedQueue()


def run_lerobot_aggregate(
    policy: ChunkSource,
    trace: list[float],
    start: np.ndarray,
    dt: float,
    total_steps: int,
    threshold: float = 0.5,
    queue: LeRobotQueue | ReimplementedQueue | None = None,
) -> Stream:
    """LeRobot-async-style action queue with weighted-average aggregation; ``total_steps`` played.

    ``queue`` is LeRobot's own (``LeRobotQueue``) where it is installed, else the reimplementation;
    the stream's ``implementation`` says which ran."""
    policy.reset()
    queue = queue if queue is not None else lerobot_queue_or_reimplementation(threshold)
    q = np.asarray(start, dtype=float).copy()
    in_flight: tuple[float, int, np.ndarray] | None = None  # (arrival time, obs timestep, chunk)
    out, seams = [q.copy()], []
    played = call = tick = 0
    holding = False
    fresh = False  # the queue's head came from a chunk that has not been played yet
    while played < total_steps:
        now = tick * dt
        if in_flight is not None and in_flight[0] <= now + 1e-9:
            _, obs_step, chunk = in_flight
            in_flight = None
            queue.merge(obs_step, chunk)
            fresh = True
        if tick > 0:  # tick 0 is the observed start
            if len(queue):
                q = queue.pop()
                played += 1
                holding = False
                if fresh:
                    seams.append(len(out))
                    fresh = False
            elif played and not holding:
                seams.append(len(out))  # the queue ran dry: the arm stops at a chunk boundary
                holding = True
            out.append(q.copy())
        if in_flight is None and queue.ready(policy.chunk_steps, threshold):
            latency = trace[call % len(trace)]
            in_flight = (now + latency, max(queue.latest_action, 0), policy.chunk(call, q))
            call += 1
        tick += 1
    return Stream(dt, np.array(out), seams, call, queue.implementation)


def cubic_spline_velocities(times: np.ndarray, positions: np.ndarray, start_velocity: np.ndarray) -> np.ndarray:
    """Knot velocities of the C2 cubic spline through ``positions`` (N x J) at ``times``, with
    ``start_velocity`` at the first knot and rest at the last: the tridiagonal system of JTC's
    ``fill_cubic_spline_velocities`` (continuous acceleration at every interior knot)."""
    n, joints = positions.shape
    if n < 2:
        return np.zeros_like(positions)
    h = np.diff(times)
    matrix = np.zeros((n, n))
    rhs = np.zeros((n, joints))
    matrix[0, 0] = matrix[-1, -1] = 1.0
    rhs[0] = start_velocity
    for i in range(1, n - 1):
        matrix[i, i - 1], matrix[i, i], matrix[i, i + 1] = 1 / h[i - 1], 2 * (1 / h[i - 1] + 1 / h[i]), 1 / h[i]
        rhs[i] = 3 * ((positions[i + 1] - positions[i]) / h[i] ** 2 + (positions[i] - positions[i - 1]) / h[i - 1] ** 2)
    return np.linalg.solve(matrix, rhs)


def run_jtc_newest_wins(
    policy: ChunkSource, trace: list[float], start: np.ndarray, dt: float, total_steps: int, request_every: int
) -> Stream:
    """ros2_controllers' newest-wins streaming into a JTC (see the module docstring): chunks are
    asked for during ``total_steps`` ticks from the first chunk's arrival, then the last one plays
    to its end."""
    policy.reset()
    current = JtcTrajectory.hold(0.0, np.asarray(start, dtype=float))
    q = np.asarray(start, dtype=float).copy()
    in_flight: tuple[float, np.ndarray] | None = (trace[0], policy.chunk(0, q))
    out, seams = [q.copy()], []
    call, played, tick, asked = 1, 0, 0, 0
    while played < total_steps or in_flight is not None or tick * dt < current.end_time:
        tick += 1
        now = tick * dt
        if in_flight is not None and in_flight[0] <= now + 1e-9:
            arrival, chunk = in_flight
            in_flight = None
            state = current.sample(arrival)
            times = dt * np.arange(1, len(chunk) + 1)
            velocities = cubic_spline_velocities(times, chunk, state.velocity)
            current = merge_at_arrival(current, JtcPoints.build(times, chunk, velocities), 0.0, arrival, state)
            seams.append(len(out))
        q = current.sample(now).position
        out.append(q.copy())
        if seams:
            played += 1
        if in_flight is None and played < total_steps and tick - asked >= request_every:
            in_flight = (now + trace[call % len(trace)], policy.chunk(call, q))
            call, asked = call + 1, tick
    return Stream(dt, np.array(out), seams, call, "simulated JTC (sim.controllers.jtc_trajectory)")


@dataclass
class GlitchingPolicy:
    """``policy``, except that call ``index`` answers a chunk whose joint 0 jumps by ``jump_rad``
    from step ``from_step`` on: a policy glitch no arm may follow (0.6 rad in one 0.1 s step is
    6 rad/s, about twice the UR5e's limit)."""

    policy: TaskPolicy
    index: int = 3
    from_step: int = 10
    jump_rad: float = 0.6

    @property
    def chunk_steps(self) -> int:
        return self.policy.chunk_steps

    def reset(self) -> None:
        self.policy.reset()

    def chunk(self, index: int, observed: np.ndarray) -> np.ndarray:
        rows = self.policy.chunk(index, observed)
        if index == self.index:
            rows = rows.copy()
            rows[self.from_step :, 0] += self.jump_rad
        return rows


def setpoints_over_limits(stream: Stream, max_velocity: float, max_acceleration: float) -> int:
    """How many of the stream's setpoints are reached with a joint over the velocity or the
    acceleration limit (finite differences over ``dt``)."""
    velocity = np.diff(stream.positions, axis=0) / stream.dt
    acceleration = np.diff(velocity, axis=0) / stream.dt
    over = np.any(np.abs(velocity) > max_velocity, axis=1)
    over[1:] |= np.any(np.abs(acceleration) > max_acceleration, axis=1)
    return int(over.sum())


# --------------------------------------------------------------------------------------------
# Metrics of a commanded stream
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StreamMetrics:
    stall_fraction: float
    task_time_s: float
    motion_time_s: float
    """From the first motion to completion: the task time without the wait for the first chunk."""
    max_vel_jump: float
    max_acc_jump: float
    rms_jerk: float
    max_path_dev: float
    done: bool


def stream_metrics(stream: Stream, path: TaskPath, goal_tolerance: float = 0.02) -> StreamMetrics:
    """Metrics of the stream up to task completion.

    Task completion: the first tick after which every setpoint stays within ``goal_tolerance``
    rad (max over joints) of the path's goal. Stall: ticks between the first motion and
    completion whose setpoint equals the previous one. Velocities, accelerations and jerk are
    finite differences over ``dt``; a seam's jumps are the largest change of velocity
    (acceleration) between consecutive intervals within one tick of the seam. ``max_path_dev``
    is the largest distance (max over joints) of a setpoint from the task path: how far the
    executor cut corners.
    """
    q, dt = stream.positions, stream.dt
    far = np.abs(q - path.goal[None, :]).max(axis=1) > goal_tolerance
    done = not far[-1]
    end = int(np.flatnonzero(far)[-1]) + 1 if far.any() else 0
    end = min(end, len(q) - 1)
    moving = np.abs(np.diff(q[: end + 1], axis=0)).max(axis=1) > 1e-12
    first_move = int(np.argmax(moving)) if moving.any() else end
    stalled = int((~moving[first_move:]).sum())
    v = np.diff(q, axis=0) / dt  # v[k-1] is the velocity over (k-1, k)
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    vel_jump = acc_jump = 0.0
    for s in stream.seams:
        for k in (s - 1, s, s + 1):
            if 1 <= k - 1 and k < len(v):
                vel_jump = max(vel_jump, float(np.abs(v[k] - v[k - 1]).max()))
            if 1 <= k - 1 and k < len(a):
                acc_jump = max(acc_jump, float(np.abs(a[k] - a[k - 1]).max()))
    jerk = j[: max(1, end)]
    rms_jerk = float(np.sqrt(np.mean(jerk * jerk))) if len(jerk) else 0.0
    grid = path.at(np.arange(0.0, path.duration + 1e-9, 0.005))
    dev = max(float(np.abs(grid - row[None, :]).max(axis=1).min()) for row in q[: end + 1])
    return StreamMetrics(
        stall_fraction=stalled * dt / max(end * dt, 1e-9),
        task_time_s=end * dt,
        motion_time_s=(end - first_move) * dt,
        max_vel_jump=vel_jump,
        max_acc_jump=acc_jump,
        rms_jerk=rms_jerk,
        max_path_dev=dev,
        done=done,
    )


def sample_stream(times: np.ndarray, positions: np.ndarray, origin: float, dt: float, end: float) -> np.ndarray:
    """A stream recorded at arbitrary ``times`` (e.g. the 500 Hz control loop), resampled on the
    tick grid ``origin + k * dt`` up to ``end`` by linear interpolation (exact at ticks that
    coincide with control steps)."""
    ticks = origin + np.arange(0, int(math.floor((end - origin) / dt + 1e-9)) + 1) * dt
    return np.column_stack([np.interp(ticks, times, positions[:, j]) for j in range(positions.shape[1])])


def latency_trace(kind: str, seconds: float, calls: int, seed: int) -> list[float]:
    """``calls`` latencies: ``fixed`` (all ``seconds``) or ``lognormal`` (mean ``seconds``,
    standard deviation ``seconds``: a heavy tail, seeded)."""
    if kind == "fixed":
        return [float(seconds)] * calls
    if kind == "lognormal":
        if seconds <= 0:
            return [0.0] * calls
        sigma2 = math.log(2.0)  # sd == mean
        mu = math.log(seconds) - sigma2 / 2.0
        return np.random.default_rng(seed).lognormal(mu, math.sqrt(sigma2), calls).tolist()
    raise ValueError(f"latency trace kind must be 'fixed' or 'lognormal', got {kind!r}")
