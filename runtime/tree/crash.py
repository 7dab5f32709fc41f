"""An unexpected exception (a bug, not bad input) told in one paragraph; its traceback goes to a file.

A user never sees a traceback: ``describe_crash`` names the node whose code raised (found in the
traceback: the deepest frame whose ``self`` is one of the tree's nodes), where in the source it
was raised, and the log file that holds the full traceback (``write_traceback``: the recording
directory of a recorded run, else ``build/logs/``).
"""
from __future__ import annotations

import os
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any, Iterable

from runtime.errors import InternalError, SourceLocation
from . import node_info

DEFAULT_LOG_DIR = Path("build") / "logs"
CRASH_LOG = "error.log"
"""The traceback's file name in a recording directory (one run per directory)."""


def culprit(error: BaseException, nodes: Iterable[Any]) -> Any | None:
    """The tree node whose method raised ``error``: the deepest traceback frame owned by one of ``nodes``."""
    known = {id(node) for node in nodes}
    found = None
    tb = error.__traceback__
    while tb is not None:
        owner = tb.tb_frame.f_locals.get("self")
        if owner is not None and id(owner) in known:
            found = owner
        tb = tb.tb_next
    return found


def raised_at(error: BaseException) -> str:
    """``file:line`` of the statement that raised ``error`` (relative to the working directory when inside it)."""
    frames = traceback.extract_tb(error.__traceback__)
    if not frames:
        return "unknown location"
    last = frames[-1]
    path = Path(last.filename)
    try:
        path = path.resolve().relative_to(Path.cwd().resolve())
    except (ValueError, OSError):
        pass
    return f"{path}:{last.lineno}"


def write_traceback(error: BaseException, directory: Path | None, name: str | None = None) -> Path | None:
    """Write ``error``'s full traceback into ``directory`` (``build/logs/`` when None); None if nothing can be written."""
    name = name or f"objective-{time.strftime('%Y%m%dT%H%M%S')}-{os.getpid()}.log"
    text = "".join(traceback.format_exception(error))
    for folder in (directory or DEFAULT_LOG_DIR, Path(tempfile.gettempdir()) / "objective-logs"):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / name
            path.write_text(text, encoding="utf-8")
            return path
        except OSError:
            continue
    return None


RUN_STOPPED = "The run was stopped and its running nodes halted"
LOAD_STOPPED = "Loading stopped there; nothing was run"


def describe_crash(error: BaseException, node: Any | None, log_file: Path | None,
                   location: SourceLocation | None = None, consequence: str = RUN_STOPPED,
                   label: str | None = None) -> InternalError:
    """The one-paragraph message, shaped like every Objective error: ``file:line: Node 'name': what``.

    ``label`` names the node when there is no node object yet (a constructor that raised).
    """
    where = f"an unexpected {type(error).__name__} in {raised_at(error)}"
    detail = str(error).strip().replace("\n", " ")
    log = (f"the full traceback is in {log_file} (a bug: please report it with that file)" if log_file is not None
           else "the traceback could not be written to a file")
    what = f"{where}: {detail or 'no message'}. {consequence}; {log}"
    if node is not None:
        xml_id = node_info.xml_id(node)
        label = xml_id if node.name == xml_id else f"{xml_id} '{node.name}'"
        location = location or node_info.location(node)
    return InternalError(what, location, label)
