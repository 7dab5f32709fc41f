"""The files of a recording directory (``objective run --record DIR``), and how they are
opened: never through a symbolic link; see docs/recording.md."""
from __future__ import annotations

import os
from pathlib import Path
from typing import IO, Any, BinaryIO

MCAP_FILE = "run.mcap"
EVENTS_FILE = "events.jsonl"
JOINTS_FILE, LATENCY_FILE, VIDEO_FILE, TREE_FILE, HTML_FILE = (
    "joints.svg", "latency.svg", "cameras.mp4", "tree.svg", "report.html")
FORMER_REPORT_FILES = ("joints.png", "latency.png")
"""The plots as earlier versions wrote them."""
REPORT_FILES = (JOINTS_FILE, LATENCY_FILE, VIDEO_FILE, TREE_FILE, HTML_FILE, *FORMER_REPORT_FILES)
"""Rendered by ``recording.report``; a new recording into the same directory removes the old ones."""


def open_new(path: Path) -> BinaryIO:
    """``path`` opened for writing as a new file. Whatever is there goes first (a symbolic link is
    removed, never followed), and the file is created exclusively and without following links
    (``O_EXCL | O_NOFOLLOW``): a link planted in a recording directory never makes a run write
    over the file it points to. OSError when that cannot be done."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    return os.fdopen(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644), "wb")


def write_new(path: Path, text: str) -> Path:
    """Write ``text`` (UTF-8) as the new file ``path`` (``open_new``); returns ``path``."""
    with open_new(path) as stream:
        stream.write(text.encode("utf-8"))
    return path


def open_existing(path: Path, mode: str = "ab", encoding: str | None = None, buffering: int = -1) -> IO[Any]:
    """The file ``path`` a recording created, opened again to append (``"ab"``, ``"a"``) or to
    read and write (``"r+b"``), never through a symbolic link (OSError if ``path`` is one)."""
    flags = {"ab": os.O_WRONLY | os.O_APPEND, "a": os.O_WRONLY | os.O_APPEND, "r+b": os.O_RDWR}[mode]
    return os.fdopen(os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC), mode, buffering, encoding)


def recording_held(directory: Path) -> str | None:
    """The file of an earlier recording ``directory`` holds (``run.mcap`` or ``events.jsonl``,
    whatever it is, a link included), or None."""
    return next((name for name in (MCAP_FILE, EVENTS_FILE) if os.path.lexists(directory / name)), None)
