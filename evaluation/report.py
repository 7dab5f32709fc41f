"""``DIR/report.html``: the summary of an evaluation, its plots and every episode, linked to its
recording when one was kept. One self-contained page (inline CSS and SVG plots), in the style of
a run's report (``recording/report/html.py``)."""
from __future__ import annotations

import html
import io
from pathlib import Path
from typing import Any

from recording.report.html import CSS

from .episode import EpisodeRecord, EpisodeStatus
from .stats import wilson_interval

REPORT_FILE = "report.html"
EXTRA_CSS = ".ERROR { color: #ef6c00; } .plots { display: flex; flex-wrap: wrap; gap: 1em; } .plots svg { max-width: 48%; height: auto; }"


def _e(value: Any) -> str:
    return html.escape(str(value))


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    return "" if value is None else str(value)


def _summary_rows(summary: dict[str, Any], identity: dict[str, Any]) -> str:
    low, high = summary["success_rate_ci95"]
    rate = summary["success_rate"]
    pairs = [
        ("Objective", identity.get("objective")),
        ("policy", identity.get("policy")),
        ("policy latency", identity.get("policy_latency")),
        ("world", identity.get("world") or "default"),
        ("episodes", f"{summary['episodes']} of {summary['requested']}" + ("" if summary["complete"] else " (incomplete)")),
        ("successes", summary["successes"]),
        ("success rate", "n/a" if rate is None else f"{100 * rate:.1f} % (95 % Wilson interval {100 * low:.1f} to {100 * high:.1f} %)"),
        ("failures", summary["failures"]),
        ("errors", summary["errors"]),
    ]
    return "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in pairs if v not in (None, ""))


def _groups_table(summary: dict[str, Any]) -> str:
    groups = summary["failure_groups"]
    if not groups:
        return "<p>No failures.</p>"
    rows = "".join(
        f"<tr><td class='{_e(g['status'])}'>{_e(g['status'])}</td><td>{g['count']}</td><td>{_e(g['failing_node'] or '')}</td>"
        f"<td>{_e(g['reason'])}<br><small>e.g. seed {g['seeds'][0]}: {_e(g['example'])}</small></td>"
        f"<td>{_e(', '.join(map(str, g['seeds'][:20])) + (' ...' if len(g['seeds']) > 20 else ''))}</td></tr>"
        for g in groups
    )
    return f"<table><tr><th>status</th><th>episodes</th><th>failing node</th><th>kind of failure (or reason)</th><th>seeds</th></tr>{rows}</table>"


def _percentile_table(summary: dict[str, Any]) -> str:
    rows = []
    for name, stats in summary["percentiles"].items():
        if not stats:
            rows.append(f"<tr><th>{_e(name)}</th><td colspan='6'>not reported by these runs</td></tr>")
            continue
        cells = "".join(f"<td>{_fmt(stats.get(k))}</td>" for k in ("p50", "p90", "p95", "p99", "max", "n"))
        rows.append(f"<tr><th>{_e(name)}</th>{cells}</tr>")
    head = "<tr><th></th><th>p50</th><th>p90</th><th>p95</th><th>p99</th><th>max</th><th>episodes</th></tr>"
    return f"<table>{head}{''.join(rows)}</table>"


def _episode_rows(records: list[EpisodeRecord]) -> str:
    rows = []
    for r in sorted(records, key=lambda r: r.seed):
        policy = r.run.get("execute_policy") or {}
        link = f"<a href='{_e(r.recording)}/report.html'>recording</a>" if r.recording else ""
        rows.append(
            f"<tr id='seed-{r.seed}'><td>{r.seed}</td><td class='{r.status.value}'>{r.status.value}</td>"
            f"<td>{_e(r.failing_node or '')}</td><td>{_e(r.reason)}</td><td>{r.sim_seconds:.2f}</td><td>{r.wall_seconds:.2f}</td>"
            f"<td>{_e(_fmt(policy.get('stall_seconds')))}</td><td>{_e(_fmt(policy.get('latency_p95_s')))}</td><td>{link}</td></tr>"
        )
    head = ("<tr><th>seed</th><th>status</th><th>failing node</th><th>reason</th><th>sim s</th><th>wall s</th>"
            "<th>stall s</th><th>latency p95 s</th><th></th></tr>")
    return f"<div class='scroll'><table>{head}{''.join(rows)}</table></div>"


def _plots(records: list[EpisodeRecord]) -> str:
    """Inline SVG: the success rate as seeds accumulate (with its interval), and histograms."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ordered = sorted(records, key=lambda r: r.seed)
    if not ordered:
        return ""
    figures = []
    fig, ax = plt.subplots(figsize=(6, 3.2))
    n = list(range(1, len(ordered) + 1))
    wins = 0
    rate, low, high = [], [], []
    for i, r in enumerate(ordered, start=1):
        wins += r.status is EpisodeStatus.SUCCESS
        lo, hi = wilson_interval(wins, i)
        rate.append(wins / i)
        low.append(lo)
        high.append(hi)
    ax.fill_between(n, low, high, alpha=0.25, label="95 % Wilson interval")
    ax.plot(n, rate, label="success rate")
    colors = {EpisodeStatus.SUCCESS: "#2e7d32", EpisodeStatus.FAILURE: "#c62828", EpisodeStatus.ERROR: "#ef6c00"}
    ax.scatter(n, [-0.05] * len(n), c=[colors[r.status] for r in ordered], s=8, marker="|")
    ax.set_ylim(-0.1, 1.05)
    ax.set_xlabel("episodes (in seed order)")
    ax.set_title("success rate")
    ax.legend(loc="lower right", fontsize=8)
    figures.append(fig)
    finished = [r for r in ordered if r.status is not EpisodeStatus.ERROR]
    series: dict[str, list[float | None]] = {
        "episode time (sim s)": [r.sim_seconds for r in finished],
        "stall seconds": [r.numbers().get("execute_policy.stall_seconds") for r in finished],
        "policy latency p95 (s)": [r.numbers().get("execute_policy.latency_p95_s") for r in finished],
    }
    for title, column in series.items():
        values = [v for v in column if v is not None]
        if not values:
            continue
        fig, ax = plt.subplots(figsize=(6, 3.2))
        ax.hist(values, bins=min(30, max(5, len(values) // 3)))
        ax.set_title(title)
        ax.set_ylabel("episodes")
        figures.append(fig)
    out = []
    for fig in figures:
        buffer = io.StringIO()
        fig.tight_layout()
        fig.savefig(buffer, format="svg")
        plt.close(fig)
        svg = buffer.getvalue()
        out.append(svg[svg.index("<svg"):])
    return f"<div class='plots'>{''.join(out)}</div>"


def write_report(directory: Path, summary: dict[str, Any], records: list[EpisodeRecord], identity: dict[str, Any]) -> Path:
    title = f"Evaluation of {Path(str(identity.get('objective', ''))).name}"
    page = (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{_e(title)}</title>"
        f"<style>{CSS}{EXTRA_CSS}</style></head><body>"
        f"<h1>{_e(title)}</h1><table>{_summary_rows(summary, identity)}</table>"
        f"<h2>Plots</h2>{_plots(records)}"
        f"<h2>Failures by reason</h2>{_groups_table(summary)}"
        f"<h2>Percentiles</h2>{_percentile_table(summary)}"
        f"<h2>Episodes</h2>{_episode_rows(records)}"
        "</body></html>"
    )
    path = directory / REPORT_FILE
    partial = path.with_name(path.name + ".partial")
    partial.write_text(page, encoding="utf-8")
    partial.replace(path)
    return path
