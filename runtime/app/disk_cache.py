"""A content-keyed cache on disk, shared by processes: what a cold start can skip recomputing.

An entry is a file named by the SHA-256 of everything that determines its content (input file
bytes, settings, library versions, the source of the code that computes it), so a changed input
is a different key and a stale entry is never read. Writers write a temporary file in the same
directory and rename it into place (atomic on POSIX), so concurrent processes never see a partial
entry; two writers of one key write the same bytes. A missing or unreadable entry is a miss.
A file's digest is itself an entry (``file_sha256``), named by the file's path and ``stat``
(device, inode, size, modification and change times), so a warm start hashes no input file.

Where: ``$OBJECTIVE_CACHE_DIR``, else ``$XDG_CACHE_HOME/objective-runtime``, else
``~/.cache/objective-runtime``. ``OBJECTIVE_CACHE=off`` turns it off (every lookup misses and
nothing is written): ``benchmarks/bench_cold_start.py`` uses it to compare.

Size: every key is new after a change to an input or to the code, so old entries would pile up
(a cell binary is ~20 MB). A read marks an entry used (its modification time); at most once an
hour, a store prunes the least recently used entries until the cache fits in
``$OBJECTIVE_CACHE_MAX_MB`` (default 1024), and removes temporary files a killed writer left.
"""
from __future__ import annotations

import functools
import hashlib
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, TypeVar

T = TypeVar("T")

ENV_DIR = "OBJECTIVE_CACHE_DIR"
ENV_SWITCH = "OBJECTIVE_CACHE"
ENV_LIMIT = "OBJECTIVE_CACHE_MAX_MB"
DEFAULT_LIMIT_MB = 1024.0
PRUNE_PERIOD_S = 3600.0
"""A store prunes only when the last pruning (``PRUNE_MARKER``'s time) is older than this."""
PRUNE_MARKER = ".pruned"
STALE_TEMPORARY_S = 3600.0
"""A writer's temporary file this old was left by a process that died mid-write."""


def cache_dir() -> Path | None:
    """The cache directory, or None when the cache is off."""
    if os.environ.get(ENV_SWITCH, "").lower() in ("off", "0", "no", "false"):
        return None
    if os.environ.get(ENV_DIR):
        return Path(os.environ[ENV_DIR])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "objective-runtime"


def content_key(*parts: str | bytes | os.PathLike[str]) -> str:
    """SHA-256 over ``parts``: strings and bytes as given, paths by their file's bytes."""
    digest = hashlib.sha256()
    for part in parts:
        if isinstance(part, os.PathLike):
            data = _file_digest(os.path.abspath(part))
        elif isinstance(part, str):
            data = part.encode()
        else:
            data = bytes(part)
        digest.update(len(data).to_bytes(8, "little"))
        digest.update(data)
    return digest.hexdigest()


SETTLED_NS = 2_000_000_000
"""A file's digest is kept only once its change time is this old: the kernel stamps times at
its clock tick (a few ms), so a file written twice within one tick keeps its stamp."""


def _file_digest(path: str) -> bytes:
    """The SHA-256 of a file; hashed every time while it was changed recently. A write changes
    its size or its change time (``st_ctime_ns``, which no user call can set back); a replaced
    file has a new inode."""
    stat = os.stat(path)
    if time.time_ns() - stat.st_ctime_ns < SETTLED_NS:
        return _sha256_of(path)
    return _settled_file_digest(path, (stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns))


@functools.lru_cache(maxsize=1024)
def _settled_file_digest(path: str, stamp: tuple[int, ...]) -> bytes:
    """Kept on disk under the path and ``stat`` stamp: a warm start reads 32 bytes instead of
    hashing every input file again (the cell's meshes: 34 MB)."""
    name = hashlib.sha256("\0".join(map(str, (path, *stamp))).encode()).hexdigest()
    return cached("file_sha256", name, lambda: _sha256_of(path), _digest)


def _sha256_of(path: str) -> bytes:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").digest()


def _digest(data: bytes) -> bytes:
    if len(data) != 32:
        raise ValueError(f"a SHA-256 digest has 32 bytes, not {len(data)}")
    return data


def cached(kind: str, key: str, compute: Callable[[], bytes], decode: Callable[[bytes], T]) -> T:
    """``decode`` of the entry ``kind/key``; on a miss, or an entry ``decode`` cannot read,
    ``compute()`` the bytes and store them. A cache that cannot be written (read-only disk,
    no space) only costs the store."""
    root = cache_dir()
    path = None if root is None else root / kind / key
    if path is not None:
        try:
            value = decode(path.read_bytes())
        except Exception:  # missing, unreadable or damaged: compute it again
            pass
        else:
            _mark_used(path)
            return value
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
            value = load(str(path))
        except Exception:  # unreadable or damaged: compute it again
            pass
        else:
            _mark_used(path)
            return value
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
    _prune_when_due(path.parent.parent, keep=path)
    return True


def _mark_used(path: Path) -> None:
    """An entry just read is the most recently used: pruning removes others first."""
    try:
        os.utime(path)
    except OSError:  # a read-only cache is still read
        pass


def size_limit_bytes() -> int | None:
    """``$OBJECTIVE_CACHE_MAX_MB`` in bytes (default ``DEFAULT_LIMIT_MB``); None, after saying
    so on stderr, when it is not a number of megabytes >= 0 (the cache is then not pruned)."""
    text = os.environ.get(ENV_LIMIT, "").strip()
    try:
        limit_mb = float(text) if text else DEFAULT_LIMIT_MB
        if not limit_mb >= 0 or limit_mb == float("inf"):
            raise ValueError
    except ValueError:
        print(f"objective-runtime: {ENV_LIMIT}={text!r} is not a number of megabytes >= 0; "
              "the disk cache is not pruned", file=sys.stderr)
        return None
    return int(limit_mb * 1_000_000)


@dataclass(frozen=True)
class Entry:
    path: Path
    size_bytes: int
    used_ns: int  # when it was written or last read (its modification time)


def entries_to_remove(entries: list[Entry], limit_bytes: int, keep: Path | None = None) -> list[Path]:
    """The least recently used entries, oldest first, whose removal brings the total to at most
    ``limit_bytes``; never ``keep`` (the entry just written)."""
    total = sum(e.size_bytes for e in entries)
    remove = []
    for entry in sorted(entries, key=lambda e: e.used_ns):
        if total <= limit_bytes:
            break
        if entry.path != keep:
            remove.append(entry.path)
            total -= entry.size_bytes
    return remove


def _prune_when_due(root: Path, keep: Path) -> None:
    """Prune ``root`` when it was last pruned more than ``PRUNE_PERIOD_S`` ago (or never)."""
    marker = root / PRUNE_MARKER
    try:
        if time.time() - marker.stat().st_mtime < PRUNE_PERIOD_S:
            return
    except OSError:  # never pruned
        pass
    limit = size_limit_bytes()
    if limit is None:
        return
    try:
        marker.touch()
        prune(root, limit, keep)
    except OSError:  # another process pruned it meanwhile, or the disk went read-only
        pass


def prune(root: Path, limit_bytes: int, keep: Path | None = None) -> list[Path]:
    """Remove the least recently used entries of the cache at ``root`` until it holds at most
    ``limit_bytes``, and temporary files older than ``STALE_TEMPORARY_S``; the removed paths.
    A process reading an entry removed meanwhile computes it again."""
    entries, removed = [], []
    stale_before_ns = time.time_ns() - int(STALE_TEMPORARY_S * 1e9)
    for kind in os.scandir(root):
        if not kind.is_dir(follow_symlinks=False):
            continue
        for item in os.scandir(kind.path):
            try:
                stat = item.stat(follow_symlinks=False)
            except FileNotFoundError:  # removed by another process meanwhile
                continue
            if item.name.startswith("."):  # a writer's temporary file
                if item.name.endswith(".tmp") and stat.st_mtime_ns < stale_before_ns:
                    removed.append(Path(item.path))
            elif item.is_file(follow_symlinks=False):
                entries.append(Entry(Path(item.path), stat.st_size, stat.st_mtime_ns))
    removed += entries_to_remove(entries, limit_bytes, keep)
    for path in removed:
        try:
            path.unlink()
        except FileNotFoundError:
            pass
    return removed
