"""Room kept for the end of a recording on a filesystem that fills up.

A recording opens with ``RESERVE_FILE`` taking ``RESERVE_BYTES`` in its directory. When a write
finds the disk full, the writer stops recording, gives the room back (``release``) and writes the
recording's end into it: the run's summary, saying the recording is incomplete and why. The room
is given back too when the recording ends normally.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import IO

from .files import open_existing, open_new

RESERVE_FILE = ".room-for-the-summary"
RESERVE_BYTES = 256 << 10
"""Far more than a run summary takes (a few KiB) and ``metadata.yaml``."""


def reserve(directory: Path) -> None:
    """Take ``RESERVE_BYTES`` in ``directory`` (nothing if the disk is already too full)."""
    path = directory / RESERVE_FILE
    try:
        stream = open_new(path)
    except OSError:
        return
    try:
        os.posix_fallocate(stream.fileno(), 0, RESERVE_BYTES)
    except OSError:
        path.unlink(missing_ok=True)
    finally:
        stream.close()


def release(directory: Path) -> None:
    """Give the room back (idempotent)."""
    try:
        (directory / RESERVE_FILE).unlink(missing_ok=True)
    except OSError:
        pass


def why_not_written(err: OSError, what: str, at_s: float | None) -> str:
    """Why the recording stops: ``No space left on device (ENOSPC) writing run.mcap at 1.93 s``."""
    code = errno.errorcode.get(err.errno or 0, "")
    where = f" at {at_s:.2f} s" if at_s is not None else ""
    return f"{err.strerror or err}{f' ({code})' if code else ''} writing {what}{where}: the recording stops there, the run went on"


def append_line(path: Path, line: str) -> None:
    """Append ``line`` to the ``events.jsonl`` at ``path`` after its last whole line (a line the
    full disk cut short goes); nothing if even that cannot be written."""
    try:
        with open_existing(path, "r+b") as stream:
            _cut_torn_line(stream)
            stream.write(line.encode())
    except OSError:
        pass


def _cut_torn_line(stream: IO[bytes], block: int = 1 << 16) -> None:
    """Truncate ``stream`` after its last newline and stay there."""
    end = stream.seek(0, 2)
    at = end
    while at > 0:
        start = max(0, at - block)
        stream.seek(start)
        newline = stream.read(at - start).rfind(b"\n")
        if newline >= 0:
            at = start + newline + 1
            break
        at = start
    if at != end:
        stream.truncate(at)
    stream.seek(at)
