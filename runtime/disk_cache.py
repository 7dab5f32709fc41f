"""A content-keyed cache on disk, shared by processes: what a cold start can skip recomputing.

An entry is a file named by the SHA-256 of everything that determines its content (input file
bytes, settings, library versions, the source of the code that computes it), so a changed input
is a different key and a stale entry is never read. Writers write a temporary file in the same
directory and rename it into place (atomic on POSIX), so concurrent processes never see a partial
entry; two writers of one key write the same bytes. A missing or unreadable entry is a miss.

Where: ``$OBJECTIVE_CACHE_DIR``, else ``$XDG_CACHE_HOME/objective-runtime``, else
``~/.cache/objective-runtime``. ``OBJECTIVE_CACHE=off`` turns it off (every lookup misses and
nothing is written): ``benchmarks/bench_cold_start.py`` uses it to compare.
"""
from __future__ import annotations

import functools
import hashlib
import os
import tempfile
from pathlib import Path
from typing import Callable, TypeVar

T = TypeVar("T")

ENV_DIR = "OBJECTIVE_CACHE_DIR"
ENV_SWITCH = "OBJECTIVE_CACHE"


def cache_dir() -> Path | None:
    """The cache directory, or None when the cache is off."""
    if os.environ.get(ENV_SWITCH, "").lower() in ("off", "0", "no", "false"):
        return None
    if os.environ.get(ENV_DIR):
        return Path(os.environ[ENV_DIR])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "objective-runtime"


def content_key(*parts: str | bytes | os.PathLike) -> str:
    """SHA-256 over ``parts``: strings and bytes as given, paths by their file's bytes."""
    digest = hashlib.sha256()
    for part in parts:
        if isinstance(part, os.PathLike):
            stat = os.stat(part)
            data = _file_digest(os.fspath(part), stat.st_size, stat.st_mtime_ns)
        elif isinstance(part, str):
            data = part.encode()
        else:
            data = bytes(part)
        digest.update(len(data).to_bytes(8, "little"))
        digest.update(data)
    return digest.hexdigest()


@functools.lru_cache(maxsize=1024)
def _file_digest(path: str, size: int, mtime_ns: int) -> bytes:
    """A file's SHA-256, read once per process while its size and time stay the same."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").digest()


def cached(kind: str, key: str, compute: Callable[[], bytes], decode: Callable[[bytes], T]) -> T:
    """``decode`` of the entry ``kind/key``; on a miss, or an entry ``decode`` cannot read,
    ``compute()`` the bytes and store them. A cache that cannot be written (read-only disk,
    no space) only costs the store."""
    root = cache_dir()
    path = None if root is None else root / kind / key
    if path is not None:
        try:
            return decode(path.read_bytes())
        except Exception:  # missing, unreadable or damaged: compute it again
            pass
    data = compute()
    if path is not None:
        _store(path, data)
    return decode(data)


def cached_file(kind: str, key: str, compute: Callable[[], bytes], load: Callable[[str], T]) -> T:
    """``cached`` for an entry a library reads from a file itself: ``load(path)`` of the entry
    ``kind/key`` (MuJoCo loads a 17 MB binary model from a path 4x faster than from bytes). On a
    miss, or an entry ``load`` cannot read, ``compute()`` the bytes, store them and load the
    stored file; without a cache, or when the store fails, from a temporary file."""
    root = cache_dir()
    path = None if root is None else root / kind / key
    if path is not None and path.is_file():  # libraries complain about a missing file on stderr
        try:
            return load(str(path))
        except Exception:  # unreadable or damaged: compute it again
            pass
    data = compute()
    if path is not None and _store(path, data):
        return load(str(path))
    fd, tmp = tempfile.mkstemp(prefix=f"{kind}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        return load(tmp)
    finally:
        os.unlink(tmp)


def _store(path: Path, data: bytes) -> bool:
    """Write ``data`` to ``path`` atomically; False when it cannot be written."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name[:16]}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:
        return False
    return True
