"""The report of a recorded run: ``joints.png``, ``latency.png``, ``cameras.mp4``, ``tree.svg`` and
``report.html``, rendered from ``events.jsonl`` + ``run.mcap`` alone (``objective report DIR``).

``render_report`` writes every artifact it can; one that fails is reported (with the reason)
in ``Report.errors`` and logged, and the others are still written.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

from .data import Recording, load_recording

__all__ = ["Report", "Recording", "load_recording", "render_report"]

from ..recording.recorder import HTML_FILE, JOINTS_FILE, LATENCY_FILE, TREE_FILE, VIDEO_FILE


@dataclass
class Report:
    directory: Path
    files: dict[str, Path] = field(default_factory=dict)
    """joints, latency, video, tree, html -> the file written."""
    errors: dict[str, str] = field(default_factory=dict)


def render_report(directory: Path | str, logger: logging.Logger | None = None) -> Report:
    """Render every artifact of the recording in ``directory`` (ObjectiveError if it is not one)."""
    from .html import report_html
    from .plots import joints_plot, latency_plot
    from .tree_svg import write_tree_svg
    from .video import camera_video

    directory = Path(directory)
    recording = load_recording(directory)
    report = Report(directory)
    status = (recording.summary or {}).get("status", "unfinished")
    steps = [
        ("joints", lambda: joints_plot(recording, directory / JOINTS_FILE)),
        ("latency", lambda: latency_plot(recording, directory / LATENCY_FILE)),
        ("tree", lambda: write_tree_svg(recording.nodes, recording.final_statuses(), directory / TREE_FILE,
                                        f"{recording.tree_id}: {status}")),
    ]
    if recording.frames:
        steps.append(("video", lambda: camera_video(recording.frames, directory / VIDEO_FILE)))
    for name, render in steps:
        try:
            report.files[name] = render()
        except Exception as err:  # one broken artifact must not cost the others
            report.errors[name] = f"{type(err).__name__}: {err}"
    html_path = directory / HTML_FILE
    html_path.write_text(report_html(recording, report.files), encoding="utf-8")
    report.files["html"] = html_path
    if logger is not None:
        for name, error in report.errors.items():
            logger.warning("recording %s: the %s artifact could not be rendered: %s", directory, name, error)
    return report
