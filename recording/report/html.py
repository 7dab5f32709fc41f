"""``report.html``: one page per run: the summary, the plots, the tree, the camera video, the
recorded topics and the event timeline.

The page loads nothing from the network (inline CSS, a few lines of inline script); it refers to
the artifacts next to it by relative paths, so the recording directory is the unit to keep or
share. The script marks each figure with its decoded width (``data-natural-width``) and shows a
notice for any artifact that fails to load.
"""
from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

from .data import Recording

CSS = """
body { font-family: sans-serif; margin: 1.5em; color: #222; max-width: 1500px; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; margin-top: 1.6em; border-bottom: 1px solid #ddd; }
.SUCCESS { color: #2e7d32; } .FAILURE, .ERROR { color: #c62828; } .INTERRUPTED { color: #ef6c00; }
.partial { background: #fff3e0; padding: 0.5em; }
table { border-collapse: collapse; font-size: 0.9em; }
td, th { border: 1px solid #ddd; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #f5f5f5; }
img, video { max-width: 100%; border: 1px solid #eee; }
.scroll { max-height: 30em; overflow: auto; }
.missing { background: #ffcdd2; padding: 0.5em; }
code { font-size: 0.9em; }
"""

SCRIPT = """
document.querySelectorAll('img').forEach(function (img) {
  function mark() {
    img.dataset.naturalWidth = img.naturalWidth;
    if (!img.naturalWidth) {
      var note = document.createElement('p');
      note.className = 'missing';
      note.textContent = img.getAttribute('src') + ' could not be shown: run `objective report` on this directory again.';
      img.insertAdjacentElement('afterend', note);
    }
  }
  if (img.complete) { mark(); } else { img.addEventListener('load', mark); img.addEventListener('error', mark); }
});
"""


def _e(value: Any) -> str:
    return html.escape(str(value))


def _rows(pairs: list[tuple[str, Any]]) -> str:
    return "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in pairs if v not in (None, ""))


def _summary_table(recording: Recording) -> str:
    s = recording.summary or {}
    started = next(iter(recording.of_kind("run_started")), None)
    pairs: list[tuple[str, Any]] = [
        ("status", s.get("status", "unknown (the run did not finish)")),
        ("failing node", s.get("failing_node")),
        ("reason", s.get("reason")),
        ("kind of failure", s.get("failure_kind")),
        ("clock time", f"{s['sim_seconds']:.2f} s" if "sim_seconds" in s else None),
        ("wall time", f"{s['wall_seconds']:.2f} s" if "wall_seconds" in s else None),
        ("ticks", s.get("ticks")),
        ("seed", started["data"].get("seed") if started else None),
    ]
    policy = s.get("execute_policy") or {}
    for key in ("run_count", "chunks", "steps_executed", "stall_seconds", "rejections", "latency_p50_s", "latency_p95_s",
                "latency_max_s", "message", "rejection_reason"):
        pairs.append((f"ExecutePolicy {key.replace('_', ' ').replace('run count', 'runs')}", policy.get(key)))
    runs = policy.get("runs") or []
    for i, run in enumerate(runs if len(runs) > 1 else [], start=1):
        pairs.append((f"ExecutePolicy run {i} ({run.get('node')})",
                      f"{run.get('chunks')} chunks, {run.get('steps_executed')} steps, "
                      f"{run.get('stall_seconds')} s stalled: {run.get('message')}"))
    for warning in policy.get("warnings") or []:
        pairs.append(("ExecutePolicy warning", warning))
    return f"<table>{_rows(pairs)}</table>"


def _extras(recording: Recording) -> str:
    s = recording.summary or {}
    known = {"status", "failing_node", "reason", "failure_kind", "sim_seconds", "wall_seconds", "ticks", "execute_policy"}
    rest = {k: v for k, v in s.items() if k not in known}
    if not rest:
        return ""
    return f"<details><summary>everything else in the summary</summary><pre>{_e(json.dumps(rest, indent=2))}</pre></details>"


def _event_text(data: dict[str, Any]) -> str:
    return ", ".join(f"{k}={round(v, 4) if isinstance(v, float) else v}" for k, v in data.items())


def _timeline(recording: Recording, limit: int = 2000) -> str:
    rows = []
    for event in recording.events[:limit]:
        rows.append(f"<tr><td>{event['time']:.3f}</td><td>{_e(event['kind'])}</td><td>{_e(event['source'])}</td>"
                    f"<td>{_e(_event_text(event.get('data') or {}))}</td></tr>")
    more = f"<p>{len(recording.events) - limit} more events in events.jsonl</p>" if len(recording.events) > limit else ""
    return ('<div class="scroll"><table><tr><th>time (s)</th><th>event</th><th>source</th><th>data</th></tr>'
            + "".join(rows) + "</table></div>" + more)


def _topics(recording: Recording) -> str:
    rows = "".join(f"<tr><td><code>{_e(t)}</code></td><td>{_e(name)}</td><td>{count}</td></tr>"
                   for t, (name, count) in sorted(recording.topics.items()))
    return f"<table><tr><th>topic</th><th>type</th><th>messages</th></tr>{rows}</table>"


def _partial_note(recording: Recording) -> str:
    """A warning above everything when the recording is incomplete (the run was killed)."""
    if not recording.partial:
        return ""
    items = "".join(f"<li>{_e(reason)}</li>" for reason in recording.partial)
    return f'<p class="partial"><strong>Partial recording</strong>: this shows the run up to where it stopped.</p><ul>{items}</ul>\n'


def report_html(recording: Recording, files: dict[str, Path]) -> str:
    """The page; ``files`` maps artifact names (joints, latency, tree, video) to the files written."""
    status = (recording.summary or {}).get("status", "")
    title = f"{recording.tree_id or 'run'}: {status or 'unfinished'}"

    def figure(key: str, alt: str) -> str:
        path = files.get(key)
        return f'<img src="{_e(path.name)}" alt="{_e(alt)}">' if path is not None else f"<p>no {alt}</p>"

    video = files.get("video")
    if video is not None:
        video_html = (f'<video src="{_e(video.name)}" controls preload="metadata"></video>'
                      f"<p>{len(recording.frames)} frames: the views each policy request carried, in request order "
                      f"(<a href=\"{_e(video.name)}\">{_e(video.name)}</a>).</p>")
    else:
        video_html = "<p>no camera frames were recorded (no policy request carried images)</p>"
    links = " · ".join(f'<a href="{_e(p.name)}">{_e(p.name)}</a>' for p in files.values())
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{_e(title)}</title><style>{CSS}</style></head>
<body>
<h1>{_e(recording.tree_id or 'run')}: <span class="{_e(status)}">{_e(status or 'unfinished')}</span></h1>
{_partial_note(recording)}{_summary_table(recording)}
{_extras(recording)}
<p>Files: {links} · <a href="run.mcap">run.mcap</a> (Foxglove, <code>ros2 bag</code>) · <a href="events.jsonl">events.jsonl</a></p>
<h2>Joints: commanded versus measured</h2>
{figure("joints", "joint plot")}
<h2>Policy latency</h2>
{figure("latency", "latency plot")}
<h2>Tree</h2>
{figure("tree", "behavior tree")}
<h2>Cameras</h2>
{video_html}
<h2>Recorded topics</h2>
{_topics(recording)}
<h2>Events</h2>
{_timeline(recording)}
<script>{SCRIPT}</script>
</body></html>
"""
