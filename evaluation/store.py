"""An evaluation's directory: ``eval.json`` (what made it), ``episodes.jsonl`` (one line per
finished episode, appended as each finishes), ``summary.json``, and ``eval.lock``, held while an
evaluation runs there (a second evaluation of the same DIR is refused, naming the first's pid).

``episodes.jsonl`` is the source of truth: a resumed evaluation reads it and skips its seeds. A
last line cut short (the machine stopped mid-write) is not an episode; it is dropped when the
file is next opened for appending, so the file always holds complete lines only.
"""
from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path
from typing import Any, BinaryIO, TextIO

from runtime.errors import ObjectiveError

from .config import identity_mismatch
from .episode import EpisodeRecord

MANIFEST_FILE = "eval.json"
EPISODES_FILE = "episodes.jsonl"
SUMMARY_FILE = "summary.json"
LOCK_FILE = "eval.lock"
"""Held by the evaluation running in DIR: a second one on the same DIR is refused."""


def read_episodes(path: Path) -> tuple[dict[int, EpisodeRecord], int]:
    """The records in ``path`` by seed (the first line of a seed wins) and the byte length of its
    complete lines (what follows is a cut-off line)."""
    records: dict[int, EpisodeRecord] = {}
    if not path.exists():
        return records, 0
    data = path.read_bytes()
    good = 0
    for number, line in enumerate(data.splitlines(keepends=True), start=1):
        if not line.endswith(b"\n"):
            break
        try:
            record = EpisodeRecord.from_json(json.loads(line))
        except (ValueError, KeyError, TypeError) as err:
            raise ObjectiveError(f"{path}:{number}: not an episode record ({err}); move the file away to start over") from None
        records.setdefault(record.seed, record)
        good += len(line)
    return records, good


class EvalStore:
    """Opens (or creates) DIR for an evaluation whose identity is ``identity``."""

    def __init__(self, out: Path, identity: dict[str, Any]) -> None:
        self.out = out
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ObjectiveError(f"--out {out}: cannot create it ({err.strerror})") from None
        self._lock = _lock(out)
        try:
            self._open(identity)
        except BaseException:
            self._lock.close()
            raise

    def _open(self, identity: dict[str, Any]) -> None:
        out = self.out
        manifest = out / MANIFEST_FILE
        episodes = out / EPISODES_FILE
        if manifest.exists():
            try:
                stored = json.loads(manifest.read_text(encoding="utf-8"))["identity"]
            except (ValueError, KeyError, TypeError):
                raise ObjectiveError(f"{manifest}: not an evaluation manifest; use another --out") from None
            mismatch = identity_mismatch(stored, identity)
            if mismatch:
                raise ObjectiveError(f"--out {out} {mismatch}; use another --out to evaluate this one")
        elif episodes.exists():
            raise ObjectiveError(f"--out {out} has {EPISODES_FILE} but no {MANIFEST_FILE}: not made by `objective eval`")
        else:
            _write_json(manifest, {"identity": identity})
        self.records, good = read_episodes(episodes)
        with open(episodes, "ab") as handle:
            handle.truncate(good)
        self._file: TextIO | None = open(episodes, "a", encoding="utf-8")

    def add(self, record: EpisodeRecord) -> bool:
        """Append ``record`` unless its seed is already there; True when it was written."""
        if record.seed in self.records or self._file is None:
            return False
        self.records[record.seed] = record
        self._file.write(json.dumps(record.to_json(), default=str) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())
        return True

    def write_summary(self, summary: dict[str, Any]) -> Path:
        path = self.out / SUMMARY_FILE
        _write_json(path, summary)
        return path

    def close(self) -> None:
        """Close ``episodes.jsonl`` and let another evaluation open DIR."""
        if self._file is not None:
            self._file.close()
            self._file = None
        self._lock.close()


def _lock(out: Path) -> BinaryIO:
    """Hold ``DIR/eval.lock`` (an exclusive ``flock``, released when the file is closed or the
    process ends, however it ends) and write this process's pid into it; ObjectiveError naming
    the holder's pid when another evaluation holds it."""
    path = out / LOCK_FILE
    handle = open(path, "a+b")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().decode(errors="replace").strip() or "unknown"
        handle.close()
        raise ObjectiveError(f"--out {out} is in use by another evaluation (pid {holder}); wait for it to end, "
                             "or use another --out") from None
    handle.truncate(0)
    handle.write(f"{os.getpid()}\n".encode())
    handle.flush()
    return handle


def _write_json(path: Path, data: dict[str, Any]) -> None:
    """Write whole or not at all: a reader never sees half a file."""
    partial = path.with_name(path.name + ".partial")
    partial.write_text(json.dumps(data, indent=2, default=str) + "\n", encoding="utf-8")
    partial.replace(path)
