"""``joints.svg`` and ``latency.svg``: what the arm was told versus what it did, and how long the
policy took versus how long it had.

Written directly as SVG (``recording.report.svg_chart``: each series decimated to the panel's
pixel width), so rendering the report needs no plotting library and takes a few milliseconds.
The pure helpers (``commanded_series``, ``stall_spans``, ``committed_windows``) derive the
plotted quantities from a ``Recording`` and are tested on their own.
"""
from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..files import write_new
from .data import CommandedGoal, Recording
from .svg_chart import LegendEntry, Panel, document, legend, text

SEAM_COLOR = "#1f77b4"
REQUEST_COLOR = "#7f7f7f"
STALL_COLOR = "#d62728"
LIMIT_COLOR = "#d62728"
MEASURED_COLOR = "#222222"
COMMANDED_COLOR = "#ff7f0e"
REJECTED_COLOR = "#9467bd"
SEAM_TOLERANCE = 1e-6
CHAR_WIDTH_EM = 0.6
"""A character's width in font sizes, as the legend estimates text."""


@dataclass
class Series:
    times: NDArray[np.float64]
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]


def commanded_series(goals: list[CommandedGoal], joint: str, end_s: float = np.inf) -> Series | None:
    """The commanded motion of ``joint``: each goal from its seam until the next goal takes over,
    and nothing after ``end_s`` (where the run ended: a stopped run cancelled its goal).

    That is the stitching rule of the admittance controller (a new goal replaces the old one at
    its seam time), so the result is what the controller was following at every instant.
    """
    parts = []
    ordered = sorted((g for g in goals if joint in g.names and len(g.times)), key=lambda g: g.sent_at)
    for k, goal in enumerate(ordered):
        until = ordered[k + 1].start if k + 1 < len(ordered) else np.inf
        keep = goal.times < until - SEAM_TOLERANCE if k + 1 < len(ordered) else np.ones(len(goal.times), bool)
        keep &= goal.times <= end_s + SEAM_TOLERANCE
        col = goal.names.index(joint)
        parts.append((goal.times[keep], goal.position[keep, col], goal.velocity[keep, col]))
    if not parts:
        return None
    cat = [np.concatenate([p[i] for p in parts]) for i in range(3)]
    return Series(*cat)


def run_end_s(recording: Recording) -> float | None:
    """The clock time the run ended (its summary's ``sim_seconds``), or None when it has no summary."""
    seconds = (recording.summary or {}).get("sim_seconds")
    return float(seconds) if isinstance(seconds, (int, float)) else None


def rejected_chunks(recording: Recording, joint: str) -> list[Series]:
    """Each rejected chunk's motion of ``joint`` on the clock (velocity from its steps), as
    ExecutePolicy recorded it in its ``chunk_rejected`` event; none for a chunk it could not read."""
    found = []
    for event in recording.of_kind("chunk_rejected"):
        data = event["data"]
        if joint not in data.get("joints", []) or len(data.get("times", [])) < 2:
            continue
        times = np.asarray(data["times"], dtype=float)
        position = np.asarray(data["positions"], dtype=float)[:, data["joints"].index(joint)]
        found.append(Series(times, position, np.gradient(position, times)))
    return found


def wrapped(content: str, width_px: float, font_px: float) -> list[str]:
    """``content`` in lines that fit ``width_px`` at ``font_px`` (nothing cut)."""
    return textwrap.wrap(content, max(10, int(width_px / (CHAR_WIDTH_EM * font_px)))) or [""]


def stall_spans(recording: Recording) -> list[tuple[float, float]]:
    """When the arm waited for a chunk, as ExecutePolicy counts it in ``stall_seconds``: the
    ``stall_s`` seconds before the seam of each ``chunk_executed`` (from the end of the committed
    motion's full speed), unless a ``chunk_rolled_back`` that follows takes it back, and before a
    ``policy_finished`` that ended the run while the arm waited."""
    spans: list[tuple[float, float] | None] = []
    for event in recording.events:
        kind, data = event["kind"], event["data"]
        if kind == "chunk_executed":
            spans.append(_span_before(float(data["seam_time"]), float(data.get("stall_s", 0.0))))
        elif kind == "chunk_rolled_back" and spans:
            spans[-1] = None
        elif kind == "policy_finished":
            spans.append(_span_before(float(event["time"]), float(data.get("stall_s", 0.0))))
    return [span for span in spans if span is not None]


def _span_before(end: float, seconds: float) -> tuple[float, float] | None:
    return (end - seconds, end) if seconds > 0 else None


def committed_windows(recording: Recording) -> list[float | None]:
    """Seconds of motion each executed chunk committed (its goal's duration), per chunk_executed."""
    windows: list[float | None] = []
    for event in recording.of_kind("chunk_executed"):
        seam = event["data"]["seam_time"]
        match = [g for g in recording.goals if abs(g.start - seam) < 1e-6]
        windows.append(match[-1].end - match[-1].start if match else None)
    return windows


def y_range(data: NDArray[np.float64], limits: list[float]) -> tuple[tuple[float, float], list[float], bool]:
    """The value range to show ``data`` and the ``limits`` near it: (range, limits to draw, whether
    some limit was too far from the data to draw without flattening it)."""
    finite = data[np.isfinite(data)]
    if finite.size == 0:
        return (-1.0, 1.0), [], False
    lo, hi = float(finite.min()), float(finite.max())
    span = max(hi - lo, 1e-3)
    view_lo, view_hi = lo - 0.6 * span, hi + 0.6 * span
    drawn, off_scale = [], False
    for limit in limits:
        if not np.isfinite(limit):
            continue
        if view_lo <= limit <= view_hi:
            drawn.append(limit)
            lo, hi = min(lo, limit), max(hi, limit)
        else:
            off_scale = True
    pad = 0.08 * max(hi - lo, 1e-3)
    return (lo - pad, hi + pad), drawn, off_scale


def _mark_timeline(panel: Panel, seams: list[float], requests: list[float], stalls: list[tuple[float, float]],
                   rejections: list[float]) -> None:
    for a, b in stalls:
        panel.span(a, b, STALL_COLOR)
    panel.vlines(requests, REQUEST_COLOR, dash="2,2")
    panel.vlines(seams, SEAM_COLOR, opacity=0.7)
    panel.vlines(rejections, STALL_COLOR, width=2.0)


JOINTS_WIDTH_PX, LEFT_PX, RIGHT_PX, COLUMN_GAP_PX = 1080, 78, 10, 62
ROW_PX, ROW_GAP_PX, TOP_PX, BOTTOM_PX = 100, 10, 48, 52


def joints_plot(recording: Recording, path: Path) -> Path:
    """Per joint: commanded versus measured position (left) and velocity (right) over time."""
    measured = recording.joints
    commanded_names: list[str] = []
    for goal in recording.goals:
        commanded_names.extend(n for n in goal.names if n not in commanded_names)
    names = list(commanded_names)
    if measured is not None:
        names += [n for n in measured.names if n not in names]
    if not names:
        return _message_svg(path, "no joint states or commanded trajectories were recorded", "joint plot")
    seams = [e["data"]["seam_time"] for e in recording.of_kind("chunk_executed")]
    requests = [e["time"] for e in recording.of_kind("chunk_requested")]
    rejections = [e["time"] for e in recording.of_kind("chunk_rejected")]
    stalls = stall_spans(recording)
    end_s = run_end_s(recording)
    span = _time_span(recording, measured, end_s) or (0.0, 1.0)
    panel_w = (JOINTS_WIDTH_PX - LEFT_PX - RIGHT_PX - COLUMN_GAP_PX) / 2
    height = TOP_PX + len(names) * (ROW_PX + ROW_GAP_PX) - ROW_GAP_PX + BOTTOM_PX
    body: list[str] = []
    off_scale = False
    for row, name in enumerate(names):
        command = commanded_series(recording.goals, name, np.inf if end_s is None else end_s)
        rejected = rejected_chunks(recording, name)
        limit = recording.limits.get(name, {})
        for col, quantity in enumerate(("position", "velocity")):
            series: list[tuple[NDArray[np.float64], NDArray[np.float64], str, str]] = []
            steps: tuple[list[float], list[float]] | None = None
            if measured is not None and name in measured.names:
                series.append((measured.times, getattr(measured, quantity)[:, measured.names.index(name)], MEASURED_COLOR, ""))
            if command is not None:
                series.append((command.times, getattr(command, quantity), COMMANDED_COLOR, "5,3"))
            for chunk in rejected:
                series.append((chunk.times, getattr(chunk, quantity), REJECTED_COLOR, "2,2"))
            if quantity == "position" and name not in commanded_names and recording.gripper_commands:
                t, p = zip(*recording.gripper_commands)
                steps = (list(t), list(p))
            if quantity == "position":
                bounds = [limit.get("lower"), limit.get("upper")]
            else:
                v = limit.get("max_velocity")
                bounds = [-v, v] if v is not None else []
            shown = [values for _, values, _, _ in series] + ([np.asarray(steps[1], float)] if steps else [])
            ylim, drawn, far = y_range(np.concatenate(shown) if shown else np.zeros(0), [b for b in bounds if b is not None])
            off_scale |= far
            panel = Panel(f"j{row}{col}", LEFT_PX + col * (panel_w + COLUMN_GAP_PX), TOP_PX + row * (ROW_PX + ROW_GAP_PX),
                          panel_w, ROW_PX, span, ylim)
            _mark_timeline(panel, seams, requests, stalls, rejections)
            for limit_value in drawn:
                panel.hline(limit_value, LIMIT_COLOR)
            for times, values, color, dash in series:
                panel.line(times, values, color, dash)
            if steps is not None:
                panel.steps(steps[0], steps[1], COMMANDED_COLOR, "5,3")
            panel.y_axis(4, name if col == 0 else "")
            if row == len(names) - 1:
                panel.x_axis(8, "time (s, runtime clock)")
            body.append(panel.svg())
    for col, title in enumerate(("position (rad)", "velocity (rad/s)")):
        body.append(text(LEFT_PX + col * (panel_w + COLUMN_GAP_PX) + panel_w / 2, TOP_PX - 6, title, 11, "middle"))
    entries = [
        LegendEntry("measured", MEASURED_COLOR), LegendEntry("commanded", COMMANDED_COLOR, "5,3"),
        LegendEntry("chunk seam", SEAM_COLOR), LegendEntry("policy request", REQUEST_COLOR, "2,2"),
        LegendEntry("stall (waiting for a chunk)", STALL_COLOR, patch=True), LegendEntry("joint limit", LIMIT_COLOR, "5,3"),
    ]
    if rejections:
        entries.append(LegendEntry("rejected chunk", REJECTED_COLOR, "2,2"))
    body.append(legend(entries, JOINTS_WIDTH_PX / 2, 16))
    if off_scale:
        body.append(text(JOINTS_WIDTH_PX - RIGHT_PX, height - 4, "joint limits far outside the plotted range are not drawn",
                         9, "end", LIMIT_COLOR))
    return write_new(path, document(JOINTS_WIDTH_PX, height, body, "joints: commanded versus measured"))


def _message_svg(path: Path, message: str, title: str) -> Path:
    return write_new(path, document(580, 60, [text(290, 34, message, 12, "middle")], title))


def _time_span(recording: Recording, measured: Any, end_s: float | None = None) -> tuple[float, float] | None:
    """First and last instant of the measured and commanded series, the last no later than the
    run's end ``end_s`` (None if there are none)."""
    starts, ends = [], []
    if measured is not None and len(measured.times):
        starts.append(float(measured.times[0]))
        ends.append(float(measured.times[-1]))
    for goal in recording.goals:
        if len(goal.times):
            starts.append(float(np.min(goal.times)))
            ends.append(float(np.max(goal.times)))
    for t, _ in recording.gripper_commands:
        starts.append(float(t))
        ends.append(float(t))
    if not starts:
        return None
    lo, hi = min(starts), max(ends)
    if end_s is not None and end_s > lo:
        hi = min(hi, end_s)
    pad = 0.01 * max(hi - lo, 1e-3)
    return lo - pad, hi + pad


LATENCY_WIDTH_PX, LATENCY_HEIGHT_PX = 720, 300
LOG_SCALE_RATIO = 20.0
"""A fast policy next to a long window: beyond this ratio both stay readable only on a log scale."""


def latency_scale(values: list[float]) -> tuple[tuple[float, float], bool]:
    """The y range of the latency plot and whether it is logarithmic."""
    shown = [v for v in values if v > 0]
    if not shown:
        return (0.0, 1.0), False
    if max(shown) / min(shown) > LOG_SCALE_RATIO:
        return (10.0 ** np.floor(np.log10(min(shown) / 1.5)), 10.0 ** np.ceil(np.log10(max(shown) * 1.5))), True
    return (0.0, max(shown) * 1.15), False


def latency_plot(recording: Recording, path: Path) -> Path:
    """Round trip of each executed chunk's request against the motion that chunk committed."""
    executed = recording.of_kind("chunk_executed")
    if not executed and not recording.responses:
        return _message_svg(path, "no policy calls were recorded in this run", "latency plot")
    chunks = [int(e["data"]["chunk"]) for e in executed]
    latency = [float(e["data"]["latency"]) for e in executed]
    windows = committed_windows(recording)
    stalled = [b for _, b in stall_spans(recording)]
    seams = [float(e["data"]["seam_time"]) for e in executed]
    warmup = next((r for r in recording.responses if r.get("request") == 1), None)
    known = [(c, w) for c, w in zip(chunks, windows) if w is not None]
    ylim, log_y = latency_scale(latency + [w for _, w in known] + ([float(warmup["latency"])] if warmup else []))
    last = max(chunks, default=0)
    panel = Panel("latency", 70, 52, LATENCY_WIDTH_PX - 70 - 15, LATENCY_HEIGHT_PX - 52 - 48, (-0.7, last + 0.7), ylim, log_y)
    for chunk, value, seam in zip(chunks, latency, seams):
        color = STALL_COLOR if any(abs(seam - b) < 1e-6 for b in stalled) else SEAM_COLOR
        panel.bar(chunk, 0.6, value, color)
    if warmup is not None:
        panel.bar(0, 0.6, float(warmup["latency"]), REQUEST_COLOR)
    for chunk, window in known:
        panel.dash_marker(chunk, 0.4, window, COMMANDED_COLOR)
    rejected = recording.of_kind("chunk_rejected")
    body: list[str] = []
    if rejected:
        lines = wrapped(f"rejected: {rejected[-1]['data'].get('reason', '')}", panel.width - 12, 10)
        body.extend(text(panel.x + 6, panel.y + 14 + 12 * k, line, 10, color=STALL_COLOR) for k, line in enumerate(lines))
    ticks = [float(c) for c in range(0, last + 1)] if last <= 40 else None
    panel.x_axis(10, "chunk (0 = warmup request)", 10, ticks, [str(int(t)) for t in ticks] if ticks else None)
    panel.y_axis(5, "seconds (log scale)" if log_y else "seconds", 10)
    body.insert(0, panel.svg())
    body.append(text(LATENCY_WIDTH_PX / 2, 16, "Policy round trip per chunk versus the motion the chunk committed "
                     "(latency above it stalls)", 11, "middle"))
    body.append(legend([
        LegendEntry("request latency", SEAM_COLOR, patch=True, opacity=1.0),
        LegendEntry("stalled before its seam", STALL_COLOR, patch=True, opacity=1.0),
        LegendEntry("committed window", COMMANDED_COLOR), LegendEntry("warmup (discarded)", REQUEST_COLOR, patch=True, opacity=1.0),
    ], LATENCY_WIDTH_PX / 2, 36))
    return write_new(path, document(LATENCY_WIDTH_PX, LATENCY_HEIGHT_PX, body, "policy latency per chunk"))
