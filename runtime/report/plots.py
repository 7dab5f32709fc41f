"""``joints.png`` and ``latency.png``: what the arm was told versus what it did, and how long the
policy took versus how long it had.

Drawn with matplotlib's object API on the Agg canvas (no pyplot: no global figure state, no
display needed). The pure helpers (``commanded_series``, ``stall_spans``, ``committed_windows``)
derive the plotted quantities from a ``Recording`` and are tested on their own.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, NullLocator

from .data import CommandedGoal, Recording

SEAM_COLOR = "#1f77b4"
REQUEST_COLOR = "#7f7f7f"
STALL_COLOR = "#d62728"
LIMIT_COLOR = "#d62728"
MEASURED_COLOR = "#222222"
COMMANDED_COLOR = "#ff7f0e"
SEAM_TOLERANCE = 1e-6


@dataclass
class Series:
    times: np.ndarray
    position: np.ndarray
    velocity: np.ndarray


def commanded_series(goals: list[CommandedGoal], joint: str) -> Series | None:
    """The commanded motion of ``joint``: each goal from its seam until the next goal takes over.

    That is the stitching rule of the admittance controller (a new goal replaces the old one at
    its seam time), so the result is what the controller was following at every instant.
    """
    parts = []
    ordered = sorted((g for g in goals if joint in g.names and len(g.times)), key=lambda g: g.sent_at)
    for k, goal in enumerate(ordered):
        until = ordered[k + 1].start if k + 1 < len(ordered) else np.inf
        keep = goal.times < until - SEAM_TOLERANCE if k + 1 < len(ordered) else np.ones(len(goal.times), bool)
        col = goal.names.index(joint)
        parts.append((goal.times[keep], goal.position[keep, col], goal.velocity[keep, col]))
    if not parts:
        return None
    cat = [np.concatenate([p[i] for p in parts]) for i in range(3)]
    return Series(*cat)


def policy_goals(recording: Recording) -> list[CommandedGoal]:
    """The goals ExecutePolicy sent for its chunks (matched to ``chunk_executed`` by seam time)."""
    seams = [e["data"]["seam_time"] for e in recording.of_kind("chunk_executed")]
    out = []
    for seam in seams:
        match = [g for g in recording.goals if abs(g.start - seam) < 1e-6]
        if match:
            out.append(match[-1])
    return out


def stall_spans(recording: Recording) -> list[tuple[float, float]]:
    """Intervals where the committed motion had drained before the next chunk's seam."""
    goals = policy_goals(recording)
    return [(a.end, b.start) for a, b in zip(goals, goals[1:]) if b.start > a.end + SEAM_TOLERANCE]


def committed_windows(recording: Recording) -> list[float | None]:
    """Seconds of motion each executed chunk committed (its goal's duration), per chunk_executed."""
    windows: list[float | None] = []
    for event in recording.of_kind("chunk_executed"):
        seam = event["data"]["seam_time"]
        match = [g for g in recording.goals if abs(g.start - seam) < 1e-6]
        windows.append(match[-1].end - match[-1].start if match else None)
    return windows


def _save(fig: Figure, path: Path, dpi: int) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=dpi)
    return path


def _limits_on(ax: Any, data: np.ndarray, limits: list[float]) -> bool:
    """Draw the limits that are near the data (and scale the axis to show them).

    Returns True when some limit was too far from the data to draw without flattening it.
    """
    finite = data[np.isfinite(data)]
    if finite.size == 0:
        return False
    lo, hi = float(finite.min()), float(finite.max())
    span = max(hi - lo, 1e-3)
    view_lo, view_hi = lo - 0.6 * span, hi + 0.6 * span
    off_scale = False
    for limit in limits:
        if not np.isfinite(limit):
            continue
        if view_lo <= limit <= view_hi:
            ax.axhline(limit, color=LIMIT_COLOR, linestyle="--", linewidth=1.0)
            lo, hi = min(lo, limit), max(hi, limit)
        else:
            off_scale = True
    pad = 0.08 * max(hi - lo, 1e-3)
    ax.set_ylim(lo - pad, hi + pad)
    return off_scale


def _mark_timeline(ax: Any, seams: list[float], requests: list[float], stalls: list[tuple[float, float]],
                   rejections: list[float]) -> None:
    # One collection per kind, spanning the axes' height: far cheaper than a line per instant.
    across = ax.get_xaxis_transform()
    for times, style in ((requests, dict(colors=REQUEST_COLOR, linestyles=":", linewidths=0.8)),
                         (seams, dict(colors=SEAM_COLOR, linewidths=0.8, alpha=0.7)),
                         (rejections, dict(colors=STALL_COLOR, linewidths=2.0))):
        if times:
            ax.add_collection(LineCollection([[(t, 0.0), (t, 1.0)] for t in times], transform=across, **style), autolim=False)
    for a, b in stalls:
        ax.axvspan(a, b, color=STALL_COLOR, alpha=0.25, linewidth=0)


def joints_plot(recording: Recording, path: Path, dpi: int = 72) -> Path:
    """Per joint: commanded versus measured position (left) and velocity (right) over time."""
    measured = recording.joints
    commanded_names: list[str] = []
    for goal in recording.goals:
        commanded_names.extend(n for n in goal.names if n not in commanded_names)
    names = list(commanded_names)
    if measured is not None:
        names += [n for n in measured.names if n not in names]
    if not names:
        fig = Figure(figsize=(8, 2))
        fig.text(0.5, 0.5, "no joint states or commanded trajectories were recorded", ha="center", va="center")
        return _save(fig, path, dpi)

    seams = [e["data"]["seam_time"] for e in recording.of_kind("chunk_executed")]
    requests = [e["time"] for e in recording.of_kind("chunk_requested")]
    rejections = [e["time"] for e in recording.of_kind("chunk_rejected")]
    stalls = stall_spans(recording)
    off_scale = False
    height = 1.7 * len(names) + 1.0
    fig = Figure(figsize=(15, height))
    # Not sharex: shared axes share one tick locator, and ticks are most of the drawing cost; the
    # rows above the last get no x ticks at all, and every axes the same time range.
    axes = fig.subplots(len(names), 2, squeeze=False)
    span = _time_span(recording, measured)
    # Fixed margins: the constrained-layout solver costs more than all the drawing here.
    fig.subplots_adjust(left=0.075, right=0.99, bottom=0.55 / height, top=1 - 0.65 / height, wspace=0.16, hspace=0.12)
    for row, name in enumerate(names):
        command = commanded_series(recording.goals, name)
        limit = recording.limits.get(name, {})
        for col, quantity in enumerate(("position", "velocity")):
            ax = axes[row][col]
            shown = []
            if measured is not None and name in measured.names:
                values = getattr(measured, quantity)[:, measured.names.index(name)]
                ax.plot(measured.times, values, color=MEASURED_COLOR, linewidth=1.0, label="measured")
                shown.append(values)
            if command is not None:
                values = getattr(command, quantity)
                ax.plot(command.times, values, color=COMMANDED_COLOR, linewidth=1.0, linestyle="--", label="commanded")
                shown.append(values)
            if quantity == "position" and name not in commanded_names and recording.gripper_commands:
                t, p = zip(*recording.gripper_commands)
                ax.step(t, p, where="post", color=COMMANDED_COLOR, linewidth=1.0, linestyle="--", label="commanded")
                shown.append(np.asarray(p))
            _mark_timeline(ax, seams, requests, stalls, rejections)
            if quantity == "position":
                bounds = [limit.get("lower"), limit.get("upper")]
            else:
                v = limit.get("max_velocity")
                bounds = [-v, v] if v is not None else []
            off_scale |= _limits_on(ax, np.concatenate(shown) if shown else np.zeros(0), [b for b in bounds if b is not None])
            ax.tick_params(labelsize=7)
            ax.yaxis.set_major_locator(MaxNLocator(4))
            if span is not None:
                ax.set_xlim(*span)
            if row < len(names) - 1:
                ax.xaxis.set_major_locator(NullLocator())
            ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        axes[row][0].set_ylabel(name, fontsize=8)
    # Text is most of matplotlib's cost here: one label per row and per column, no grid.
    axes[0][0].set_title("position (rad)", fontsize=9)
    axes[0][1].set_title("velocity (rad/s)", fontsize=9)
    for col in range(2):
        axes[-1][col].set_xlabel("time (s, runtime clock)", fontsize=8)
        axes[-1][col].xaxis.set_major_locator(MaxNLocator(8))
    if off_scale:
        fig.text(0.99, 0.003, "joint limits far outside the plotted range are not drawn", ha="right", va="bottom",
                 fontsize=7, color=LIMIT_COLOR)
    handles = [
        _line(MEASURED_COLOR, "-", "measured"), _line(COMMANDED_COLOR, "--", "commanded"),
        _line(SEAM_COLOR, "-", "chunk seam"), _line(REQUEST_COLOR, ":", "policy request"),
        _patch(STALL_COLOR, "stall (motion drained)"), _line(LIMIT_COLOR, "--", "joint limit"),
    ]
    fig.legend(handles=handles, loc="upper center", ncols=len(handles), fontsize=8, frameon=False)
    return _save(fig, path, dpi)


def _time_span(recording: Recording, measured: Any) -> tuple[float, float] | None:
    """First and last instant of the measured and commanded series (None if there are none)."""
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
    pad = 0.01 * max(hi - lo, 1e-3)
    return lo - pad, hi + pad


def _line(color: str, style: str, label: str) -> Any:
    from matplotlib.lines import Line2D

    return Line2D([], [], color=color, linestyle=style, label=label)


def _patch(color: str, label: str) -> Any:
    from matplotlib.patches import Patch

    return Patch(color=color, alpha=0.25, label=label)


def latency_plot(recording: Recording, path: Path, dpi: int = 72) -> Path:
    """Round trip of each executed chunk's request against the motion that chunk committed."""
    executed = recording.of_kind("chunk_executed")
    fig = Figure(figsize=(10, 4))
    ax = fig.subplots()
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.13, top=0.91)  # fixed: no layout solver
    if not executed and not recording.responses:
        ax.axis("off")
        ax.text(0.5, 0.5, "no policy calls were recorded in this run", ha="center", va="center")
        return _save(fig, path, dpi)
    chunks = [int(e["data"]["chunk"]) for e in executed]
    latency = [float(e["data"]["latency"]) for e in executed]
    windows = committed_windows(recording)
    stalled = [b for _, b in stall_spans(recording)]
    seams = [float(e["data"]["seam_time"]) for e in executed]
    colors = [STALL_COLOR if any(abs(s - b) < 1e-6 for b in stalled) else SEAM_COLOR for s in seams]
    ax.bar(chunks, latency, color=colors, width=0.6, label="request latency (red: the motion stalled before its seam)")
    known = [(c, w) for c, w in zip(chunks, windows) if w is not None]
    if known:
        xs, ws = zip(*known)
        ax.scatter(xs, ws, marker="_", s=400, color=COMMANDED_COLOR, linewidths=2, label="committed window", zorder=3)
    warmup = next((r for r in recording.responses if r.get("request") == 1), None)
    if warmup is not None:
        ax.bar([0], [warmup["latency"]], color=REQUEST_COLOR, width=0.6, label="warmup (discarded)")
    rejected = recording.of_kind("chunk_rejected")
    if rejected:
        ax.text(0.01, 0.97, f"rejected: {rejected[-1]['data'].get('reason', '')}"[:160], transform=ax.transAxes,
                va="top", fontsize=8, color=STALL_COLOR)
    ax.set_xlabel("chunk (0 = warmup request)")
    ax.set_ylabel("seconds")
    shown = [v for v in latency + [w for w in windows if w is not None] if v > 0]
    if shown and max(shown) / min(shown) > 20:  # a fast policy next to a long window: both stay readable
        ax.set_yscale("log")
        ax.set_ylabel("seconds (log scale)")
    ax.set_title("Policy round trip per chunk versus the motion the chunk committed (latency above it stalls)", fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path, dpi)
