"""The report of a recorded run: ``joints.svg``, ``latency.svg``, ``cameras.mp4``, ``tree.svg`` and
``report.html``, rendered from ``events.jsonl`` + ``run.mcap`` alone (``objective report DIR``).

``render_report`` writes every artifact it can; one that fails is reported (with the reason)
in ``Report.errors`` and logged, and the others are still written.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from ..files import HTML_FILE, JOINTS_FILE, LATENCY_FILE, TREE_FILE, VIDEO_FILE, write_new

if TYPE_CHECKING:
    from .data import Recording

__all__ = ["Report", "Recording", "load_recording", "log_errors", "render_report"]


def __getattr__(name: str) -> Any:
    """``Recording`` and ``load_recording`` from ``.data`` when first used: the recording worker
    imports this package before it can drain the run's pipe, and ``.data`` takes a few tenths of a
    second (numpy, rclpy, mcap)."""
    if name in ("Recording", "load_recording"):
        from . import data

        return getattr(data, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass
class Report:
    directory: Path
    files: dict[str, Path] = field(default_factory=dict)
    """joints, latency, video, tree, html -> the file written."""
    errors: dict[str, str] = field(default_factory=dict)
    partial: list[str] = field(default_factory=list)
    """Why the recording is incomplete (``Recording.partial``); empty when it is whole."""


def render_report(directory: Path | str, logger: logging.Logger | None = None, recording: Recording | None = None,
                  video: Callable[[], Path] | None = None) -> Report:
    """Render every artifact of the recording in ``directory`` (ObjectiveError if it is not one);
    ``recording``: its data already read (the recording worker builds it as the run goes);
    ``video``: finishes a video already encoded as the frames arrived (``VideoEncoder.close``).
    """
    from .data import load_recording
    from .html import report_html
    from .plots import joints_plot, latency_plot
    from .tree_svg import write_tree_svg
    from .video import camera_video

    directory = Path(directory)
    recording = recording if recording is not None else load_recording(directory)
    report = Report(directory, partial=list(recording.partial))
    status = (recording.summary or {}).get("status", "unfinished (partial)")
    steps = [
        ("joints", lambda: joints_plot(recording, directory / JOINTS_FILE)),
        ("latency", lambda: latency_plot(recording, directory / LATENCY_FILE)),
        ("tree", lambda: write_tree_svg(recording.nodes, recording.final_statuses(), directory / TREE_FILE,
                                        f"{recording.tree_id}: {status}")),
    ]
    if recording.frames:
        steps.append(("video", video or (lambda: camera_video(recording.frames, directory / VIDEO_FILE))))
    for name, render in steps:
        _render_one(report, name, render)
    html_path = directory / HTML_FILE
    _render_one(report, "html", lambda: write_new(html_path, report_html(recording, report.files)))
    log_errors(report, logger)
    return report


def log_errors(report: Report, logger: logging.Logger | None) -> None:
    """One warning per artifact that could not be rendered."""
    if logger is not None:
        for name, error in report.errors.items():
            logger.warning("recording %s: the %s artifact could not be rendered: %s", report.directory, name, error)


def _render_one(report: Report, name: str, render: Callable[[], Path]) -> None:
    try:
        report.files[name] = render()
    except Exception as err:  # one broken artifact must not cost the others
        report.errors[name] = f"{type(err).__name__}: {err}"
