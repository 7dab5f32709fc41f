"""A small SVG chart kit for the report's plots: axes, ticks, polylines, markers, a legend.

The report draws two plots of a few thousand points each; a plotting library costs more to
import than the drawing does, so they are written directly as SVG text. The math is in pure
functions (``nice_ticks``, ``log_ticks``, ``decimate``); ``Panel`` maps data to pixels and
collects the SVG elements of one plotting area.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.sax.saxutils import escape

import numpy as np
from numpy.typing import NDArray

FONT = "font-family=\"sans-serif\""
AXIS_COLOR = "#444444"
GRID_COLOR = "#e6e6e6"


def nice_ticks(lo: float, hi: float, most: int) -> list[float]:
    """At most ``most`` round values (1, 2, 2.5 or 5 times a power of ten apart) within [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo or most < 1:
        return []
    raw = (hi - lo) / most
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 2.5, 5, 10) if m * power >= raw)
    first = math.ceil(lo / step - 1e-9)
    ticks = [k * step for k in range(first, int(math.floor(hi / step + 1e-9)) + 1)]
    return [0.0 if abs(t) < step * 1e-9 else t for t in ticks]


def log_ticks(lo: float, hi: float) -> list[float]:
    """The powers of ten within [lo, hi] (both > 0)."""
    if lo <= 0 or hi <= lo:
        return []
    return [10.0 ** k for k in range(math.ceil(math.log10(lo) - 1e-9), math.floor(math.log10(hi) + 1e-9) + 1)]


def tick_label(value: float, step: float) -> str:
    """``value`` with as many decimals as the tick spacing ``step`` needs."""
    decimals = max(0, -math.floor(math.log10(step) + 1e-9)) if step > 0 else 0
    if step > 0 and not math.isclose(round(step, decimals), step, rel_tol=1e-6):
        decimals += 1
    return f"{value:.{decimals}f}"


def decimate(times: NDArray[np.float64], values: NDArray[np.float64], buckets: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """At most ``4 * buckets`` points that draw the same line at ``buckets`` pixels of width: per
    bucket of equal time, the first, lowest, highest and last point, in time order (``times``
    ascending).

    NaN values are dropped (a joint missing from a message is not drawn as zero).
    """
    keep = np.isfinite(values) & np.isfinite(times)
    times, values = times[keep], values[keep]
    if len(times) <= 4 * buckets or buckets < 1:
        return times, values
    edges = np.linspace(times[0], times[-1], buckets + 1)
    bucket = np.clip(np.searchsorted(edges, times, side="right") - 1, 0, buckets - 1)
    starts = np.flatnonzero(np.r_[True, bucket[1:] != bucket[:-1]])
    lasts = np.r_[starts[1:], len(times)] - 1
    by_value = np.lexsort((values, bucket))  # within each bucket (contiguous: times ascend), lowest first
    index = np.unique(np.concatenate([starts, lasts, by_value[starts], by_value[lasts]]))
    return times[index], values[index]


@dataclass
class Panel:
    """One plotting area: ``x``, ``y``, ``width``, ``height`` in pixels, the data ranges, and the
    SVG elements drawn into it (clipped to it)."""

    id: str
    x: float
    y: float
    width: float
    height: float
    xlim: tuple[float, float]
    ylim: tuple[float, float]
    log_y: bool = False
    elements: list[str] = field(default_factory=list)
    axes: list[str] = field(default_factory=list)
    """Ticks and labels: drawn outside the clip region."""

    def px(self, t: NDArray[np.float64] | float) -> NDArray[np.float64] | float:
        lo, hi = self.xlim
        return self.x + (np.asarray(t, dtype=float) - lo) / (hi - lo) * self.width

    def py(self, v: NDArray[np.float64] | float) -> NDArray[np.float64] | float:
        lo, hi = self.ylim
        value = np.asarray(v, dtype=float)
        if self.log_y:
            lo, hi, value = math.log10(lo), math.log10(hi), np.log10(np.maximum(value, 1e-300))
        return self.y + self.height - (value - lo) / (hi - lo) * self.height

    def line(self, times: NDArray[np.float64], values: NDArray[np.float64], color: str, dash: str = "", width: float = 1.0) -> None:
        """A polyline through the points (NaN ones skipped), decimated to the panel's width."""
        t, v = decimate(np.asarray(times, dtype=float), np.asarray(values, dtype=float), int(self.width))
        if len(t) == 0:
            return
        xs, ys = np.round(self.px(t), 1), np.round(self.py(v), 1)
        inner = np.ones(len(ys), bool)
        inner[1:-1] = (ys[1:-1] != ys[:-2]) | (ys[1:-1] != ys[2:])  # a flat stretch needs its two ends only
        points = " ".join(map("{:.1f},{:.1f}".format, xs[inner].tolist(), ys[inner].tolist()))
        style = f' stroke-dasharray="{dash}"' if dash else ""
        self.elements.append(f'<polyline points="{points}" fill="none" stroke="{color}" stroke-width="{width}"{style}/>')

    def steps(self, times: list[float], values: list[float], color: str, dash: str = "") -> None:
        """A step line that holds each value until the next (to the panel's right edge)."""
        if not times:
            return
        ts = [t for pair in zip(times, times[1:] + [self.xlim[1]]) for t in pair]
        vs = [v for v in values for _ in range(2)]
        self.line(np.array(ts), np.array(vs), color, dash)

    def vlines(self, times: list[float], color: str, width: float = 0.8, dash: str = "", opacity: float = 1.0) -> None:
        """Vertical lines across the panel's height at ``times`` (one path for all)."""
        inside = [t for t in times if self.xlim[0] <= t <= self.xlim[1]]
        if not inside:
            return
        top, bottom = self.y, self.y + self.height
        path = " ".join(f"M{self.px(t):.1f} {top:.1f}V{bottom:.1f}" for t in inside)
        style = (f' stroke-dasharray="{dash}"' if dash else "") + (f' stroke-opacity="{opacity}"' if opacity < 1 else "")
        self.elements.append(f'<path d="{path}" stroke="{color}" stroke-width="{width}"{style} fill="none"/>')

    def hline(self, value: float, color: str, dash: str = "5,3") -> None:
        y = self.py(value)
        self.elements.append(f'<path d="M{self.x:.1f} {y:.1f}H{self.x + self.width:.1f}" stroke="{color}" '
                             f'stroke-dasharray="{dash}" fill="none"/>')

    def span(self, a: float, b: float, color: str, opacity: float = 0.25) -> None:
        x0, x1 = self.px(max(a, self.xlim[0])), self.px(min(b, self.xlim[1]))
        if x1 > x0:
            self.elements.append(f'<rect x="{x0:.1f}" y="{self.y:.1f}" width="{x1 - x0:.1f}" height="{self.height:.1f}" '
                                 f'fill="{color}" fill-opacity="{opacity}"/>')

    def bar(self, center: float, bar_width: float, value: float, color: str) -> None:
        x0, x1 = self.px(center - bar_width / 2), self.px(center + bar_width / 2)
        base = self.ylim[0] if self.log_y else max(self.ylim[0], 0.0)
        top, bottom = self.py(value), self.py(base)
        self.elements.append(f'<rect class="bar" x="{x0:.1f}" y="{min(top, bottom):.1f}" width="{x1 - x0:.1f}" '
                             f'height="{abs(bottom - top):.1f}" fill="{color}"/>')

    def dash_marker(self, center: float, half_width: float, value: float, color: str) -> None:
        """A short horizontal line at ``value`` (the committed window above a latency bar)."""
        y = self.py(value)
        self.elements.append(f'<path d="M{self.px(center - half_width):.1f} {y:.1f}H{self.px(center + half_width):.1f}" '
                             f'stroke="{color}" stroke-width="2.5"/>')

    def y_axis(self, most: int = 4, label: str = "", font_px: float = 9) -> None:
        lo, hi = self.ylim
        ticks = log_ticks(lo, hi) if self.log_y else nice_ticks(lo, hi, most)
        step = ticks[1] - ticks[0] if len(ticks) > 1 else abs(hi - lo) or 1.0
        for tick in ticks:
            y = self.py(tick)
            text = f"{tick:g}" if self.log_y else tick_label(tick, step)
            self.axes.append(f'<path d="M{self.x - 3:.1f} {y:.1f}H{self.x:.1f}" stroke="{AXIS_COLOR}"/>'
                             f'<text x="{self.x - 5:.1f}" y="{y + font_px / 3:.1f}" text-anchor="end" '
                             f'font-size="{font_px}" {FONT}>{text}</text>')
        if label:
            cx, cy = self.x - 52, self.y + self.height / 2
            self.axes.append(f'<text x="{cx:.1f}" y="{cy:.1f}" transform="rotate(-90 {cx:.1f} {cy:.1f})" '
                             f'text-anchor="middle" font-size="{font_px + 1}" {FONT}>{escape(label)}</text>')

    def x_axis(self, most: int = 8, label: str = "", font_px: float = 9,
               ticks: list[float] | None = None, labels: list[str] | None = None) -> None:
        lo, hi = self.xlim
        ticks = nice_ticks(lo, hi, most) if ticks is None else ticks
        step = ticks[1] - ticks[0] if len(ticks) > 1 else 1.0
        bottom = self.y + self.height
        for k, tick in enumerate(ticks):
            x = self.px(tick)
            text = labels[k] if labels is not None else tick_label(tick, step)
            self.axes.append(f'<path d="M{x:.1f} {bottom:.1f}V{bottom + 3:.1f}" stroke="{AXIS_COLOR}"/>'
                             f'<text x="{x:.1f}" y="{bottom + 5 + font_px:.1f}" text-anchor="middle" '
                             f'font-size="{font_px}" {FONT}>{escape(text)}</text>')
        if label:
            self.axes.append(f'<text x="{self.x + self.width / 2:.1f}" y="{bottom + 18 + font_px:.1f}" '
                             f'text-anchor="middle" font-size="{font_px + 1}" {FONT}>{escape(label)}</text>')

    def svg(self) -> str:
        clip = f"clip-{self.id}"
        frame = (f'<rect x="{self.x:.1f}" y="{self.y:.1f}" width="{self.width:.1f}" height="{self.height:.1f}" '
                 f'fill="none" stroke="{AXIS_COLOR}" stroke-width="0.8"/>')
        return (f'<clipPath id="{clip}"><rect x="{self.x:.1f}" y="{self.y:.1f}" width="{self.width:.1f}" '
                f'height="{self.height:.1f}"/></clipPath><g clip-path="url(#{clip})">{"".join(self.elements)}</g>'
                f'{frame}{"".join(self.axes)}')


@dataclass
class LegendEntry:
    label: str
    color: str
    dash: str = ""
    patch: bool = False
    """A filled square (a span, a bar) instead of a line."""
    opacity: float = 0.25


def legend(entries: list[LegendEntry], center_x: float, y: float, font_px: float = 10) -> str:
    """One row of legend entries, centred on ``center_x`` (text width estimated from its length)."""
    widths = [30 + 0.6 * font_px * len(e.label) + 16 for e in entries]
    x = center_x - sum(widths) / 2
    parts = []
    for entry, width in zip(entries, widths):
        if entry.patch:
            parts.append(f'<rect x="{x:.1f}" y="{y - 6:.1f}" width="22" height="10" fill="{entry.color}" fill-opacity="{entry.opacity}"/>')
        else:
            dash = f' stroke-dasharray="{entry.dash}"' if entry.dash else ""
            parts.append(f'<path d="M{x:.1f} {y - 1:.1f}h22" stroke="{entry.color}" stroke-width="1.5"{dash}/>')
        parts.append(f'<text x="{x + 28:.1f}" y="{y + 3:.1f}" font-size="{font_px}" {FONT}>{escape(entry.label)}</text>')
        x += width
    return "".join(parts)


def document(width: float, height: float, body: list[str], title: str) -> str:
    """A standalone SVG file (white background) with ``body`` inside."""
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" height="{height:.0f}" '
            f'viewBox="0 0 {width:.0f} {height:.0f}"><title>{escape(title)}</title>'
            f'<rect width="100%" height="100%" fill="white"/>{"".join(body)}</svg>\n')


def text(x: float, y: float, content: str, font_px: float = 10, anchor: str = "start", color: str = "#222222") -> str:
    return (f'<text x="{x:.1f}" y="{y:.1f}" text-anchor="{anchor}" font-size="{font_px}" fill="{color}" '
            f'{FONT}>{escape(content)}</text>')
