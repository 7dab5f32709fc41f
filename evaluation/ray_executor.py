"""The Ray executor: one Ray actor per worker, each keeping its loaded world between episodes.

``--executor ray`` without ``--ray-address`` starts a local Ray instance sized to ``--workers``
(loopback only, no dashboard); with an address it joins that cluster. The driver (the
``objective eval`` process) puts the inputs into Ray's object store once: the Objective with the
``*.xml`` beside it and in ``--path`` folders, and the replay file or the LeRobot checkpoint's
files. Each actor unpacks them into a scratch folder on its node, so a worker node needs only
the project installed (``pip install -e '.[ray]'``, plus ``make lerobot`` for checkpoints), not
the files. Kept recordings come back the same way (a tar archive per episode) and are unpacked
into ``DIR/recordings/`` by the driver.

Each actor runs one episode at a time; the driver collects results as they finish and writes
each at once. An actor that dies (a crash, its node lost) is replaced by a new one, which Ray
places wherever there is room, and its episode runs again (``--retries``); an episode over
``--episode-timeout`` has its actor killed and replaced.
"""
from __future__ import annotations

import dataclasses
import io
import logging
import os
import shutil
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

from runtime.errors import ObjectiveError, error_kind

from .config import WorkerSpec
from .episode import EpisodeRecord
from .executors import Event, EventKind, SlotPool, SlotState
from .policies import PolicyKind, parse_policy

INPUT_LIMIT_BYTES = 2 << 30
"""Inputs larger than this are refused (put the checkpoint behind an inference server instead)."""


LOOPBACK_ONLY_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
"""Set to 0 before Ray is imported, Ray takes 127.0.0.1 as this node's address (by default it
resolves 127.0.0.1 to the machine's outward address): a local instance stays on loopback."""


WORKER_NICENESS_ENV = "RAY_worker_niceness"
"""Ray starts its workers at niceness 15 by default: on a machine shared with other work they then
get a fraction of a core. A local instance starts them at 0, like the local executor's."""


def ray_module(local: bool) -> Any:
    if local:
        os.environ.setdefault(LOOPBACK_ONLY_ENV, "0")
        os.environ.setdefault(WORKER_NICENESS_ENV, "0")
    try:
        import ray
    except ImportError:
        raise ObjectiveError("--executor ray needs Ray: install it with `make ray` (pip install -e '.[ray]')") from None
    return ray


# -- inputs shipped to the workers --------------------------------------------------------------
def pack_inputs(spec: WorkerSpec) -> dict[str, Any]:
    """The files a worker needs, as {"objective": {name: bytes}, "paths": [...], "policy": {...}}."""
    objective_dir = spec.objective.parent
    inputs: dict[str, Any] = {
        "objective_name": spec.objective.name,
        "objective": {p.name: p.read_bytes() for p in sorted(objective_dir.glob("*.xml"))},
        "paths": [{p.name: p.read_bytes() for p in sorted(d.glob("*.xml"))} for d in spec.search_paths],
        "objectives_dir": {p.name: p.read_bytes() for p in sorted(spec.objectives_dir.glob("*.xml"))} if spec.objectives_dir else None,
        "policy": None,
        "shown_as": {
            "objective": _shown(objective_dir),
            "paths": [_shown(d) for d in spec.search_paths],
            "library": _shown(spec.objectives_dir) if spec.objectives_dir else None,
        },
    }
    inputs["objective"][spec.objective.name] = spec.objective.read_bytes()
    path = spec.policy.path
    if path is not None:
        files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        size = sum(f.stat().st_size for f in files)
        if size > INPUT_LIMIT_BYTES:
            raise ObjectiveError(f"--policy {spec.policy.text}: {size / 2**30:.1f} GiB is too large to send to Ray "
                                 "workers; serve it with `objective serve` and use --policy http(s)://...")
        inputs["policy"] = {str(f.relative_to(path) if f != path else f.name): f.read_bytes() for f in files}
    return inputs


def _shown(folder: Path) -> str:
    """How the loader names files in ``folder`` in this process (relative to the working directory when under it)."""
    return os.path.relpath(folder) if folder.resolve().is_relative_to(Path.cwd()) else str(folder)


def relocate(text: str | None, folders: list[tuple[Path, str | None]]) -> str | None:
    """``text`` with each unpacked folder's path replaced by the driver's name for it."""
    if not text:
        return text
    for local, shown in folders:
        if shown is not None:
            text = text.replace(f"{local}/", "" if shown == "." else f"{shown}/")
    return text


def unpack_inputs(spec: WorkerSpec, inputs: dict[str, Any], root: Path) -> WorkerSpec:
    """Write ``inputs`` under ``root`` and return ``spec`` pointing at those copies."""

    def write(folder: Path, files: dict[str, bytes]) -> Path:
        for name, data in files.items():
            target = folder / name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
        return folder

    objective = write(root / "objective", inputs["objective"]) / inputs["objective_name"]
    paths = tuple(write(root / f"path-{i}", files) for i, files in enumerate(inputs["paths"]))
    library = write(root / "library", inputs["objectives_dir"]) if inputs["objectives_dir"] is not None else None
    policy = spec.policy
    if inputs["policy"] is not None:
        folder = write(root / "policy", inputs["policy"])
        single_file = policy.kind in (PolicyKind.REPLAY, PolicyKind.FACTORY)
        local = folder / next(iter(inputs["policy"])) if single_file else folder
        factory = policy.text.rpartition(":")[2]  # FILE.py:NAME travels as its file
        policy = parse_policy(f"{local}:{factory}" if policy.kind is PolicyKind.FACTORY else f"{policy.kind.value}:{local}")
    return dataclasses.replace(spec, objective=objective, search_paths=paths, objectives_dir=library, policy=policy)


def pack_recording(folder: Path) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as archive:
        archive.add(folder, arcname=folder.name)
    return buffer.getvalue()


def unpack_recording(data: bytes, destination: Path) -> None:
    destination.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as archive:
        archive.extractall(destination, filter="data")


class EpisodeActor:
    """A Ray actor around an ``EpisodeWorker`` (created with ``ray.remote`` by the executor)."""

    def __init__(self, spec: WorkerSpec, inputs: dict[str, Any], name: str) -> None:
        from .worker import EpisodeWorker

        self.scratch = Path(tempfile.mkdtemp(prefix="objective-eval-"))
        local = unpack_inputs(spec, inputs, self.scratch / "inputs")
        shown = inputs["shown_as"]
        self.folders = [(local.objective.parent, shown["objective"]), *zip(local.search_paths, shown["paths"])]
        if local.objectives_dir is not None:
            self.folders.append((local.objectives_dir, shown["library"]))
        recordings = self.scratch / "recordings" if spec.record.value != "none" else None
        self.worker = EpisodeWorker(local, name, recordings)

    def warm_up(self) -> dict[str, Any]:
        import socket

        return {**self.worker.warm_up(), "node": socket.gethostname()}

    def run(self, seed: int) -> tuple[dict[str, Any], bytes | None]:
        record = self.worker.run(seed)
        record.failing_location = relocate(record.failing_location, self.folders)
        record.reason = relocate(record.reason, self.folders) or ""
        archive = None
        if record.recording:
            folder = self.scratch / record.recording
            archive = pack_recording(folder)
            shutil.rmtree(folder, ignore_errors=True)
        return record.to_json(), archive

    def close(self) -> None:
        self.worker.close()
        shutil.rmtree(self.scratch, ignore_errors=True)


@dataclasses.dataclass
class _ActorSlot:
    index: int
    actor: Any
    ref: Any
    state: SlotState = SlotState.LOADING
    since: float = dataclasses.field(default_factory=time.monotonic)
    seed: int | None = None
    generation: int = 0

    @property
    def name(self) -> str:
        return f"ray-worker-{self.index}.{self.generation}"


class RayExecutor(SlotPool):
    """``workers`` Ray actors; implements ``evaluation.executors.Executor``."""

    def __init__(self, spec: WorkerSpec, workers: int, out: Path, episode_timeout_s: float, address: str | None = None) -> None:
        ray = ray_module(local=not address)
        self.ray, self.spec, self.workers, self.out, self.episode_timeout_s = ray, spec, workers, out, episode_timeout_s
        self.owns_ray = False
        if not ray.is_initialized():
            quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
            if address:
                ray.init(address=address, **quiet)
            else:
                ray.init(num_cpus=workers, include_dashboard=False, _node_ip_address="127.0.0.1", **quiet)
            self.owns_ray = True
        self.inputs = ray.put(pack_inputs(spec))
        self.actor_class = ray.remote(num_cpus=1, max_restarts=0, max_task_retries=0)(EpisodeActor)
        self.slots = [self._spawn(i) for i in range(workers)]

    def _spawn(self, index: int, generation: int = 0) -> _ActorSlot:
        actor = self.actor_class.options(name=None).remote(self.spec, self.inputs, f"ray-worker-{index}.{generation}")
        return _ActorSlot(index, actor, actor.warm_up.remote(), generation=generation)

    def _replace(self, slot: _ActorSlot) -> None:
        self.ray.kill(slot.actor, no_restart=True)
        self.slots[slot.index] = self._spawn(slot.index, slot.generation + 1)

    # -- Executor ---
    def submit(self, seed: int) -> None:
        slot = self._take_idle(seed)
        slot.ref = slot.actor.run.remote(seed)

    def wait(self, timeout_s: float) -> list[Event]:
        now = time.monotonic()
        deadline = min([now + timeout_s] + [self._deadline(s) for s in self.slots])
        refs = [s.ref for s in self.slots if s.ref is not None]
        if refs:
            self.ray.wait(refs, num_returns=1, timeout=max(0.0, deadline - now))
            ready, _ = self.ray.wait(refs, num_returns=len(refs), timeout=0)
        else:
            time.sleep(max(0.0, deadline - now))
            ready = []
        events: list[Event] = []
        for slot in list(self.slots):
            if slot.ref is not None and slot.ref in ready:
                events.extend(self._receive(slot))
            elif time.monotonic() >= self._deadline(slot):
                events.append(self._timed_out(slot))
        return events

    def _receive(self, slot: _ActorSlot) -> list[Event]:
        ray = self.ray
        ref, slot.ref = slot.ref, None
        try:
            value = ray.get(ref)
        except ray.exceptions.RayActorError as err:
            return [self._lost(slot, err)]
        except ray.exceptions.RayTaskError as err:
            cause = err.as_instanceof_cause()
            reason = str(cause) if isinstance(cause, ObjectiveError) else f"{type(cause).__name__}: {cause}"
            if slot.state is SlotState.LOADING:
                return [Event(EventKind.LOAD_FAILED, reason=reason.splitlines()[-1] if reason else reason, worker=slot.name)]
            seed = slot.seed
            assert seed is not None  # a slot past LOADING runs a seed
            slot.state, slot.seed = SlotState.IDLE, None
            record = EpisodeRecord.error(seed, reason, worker=slot.name, kind=error_kind(cause))
            return [Event(EventKind.DONE, seed, record, worker=slot.name)]
        if slot.state is SlotState.LOADING:
            slot.state, slot.since = SlotState.IDLE, time.monotonic()
            return []
        record_json, archive = value
        record = EpisodeRecord.from_json(record_json)
        if archive is not None:
            unpack_recording(archive, self.out / "recordings")
        slot.state, slot.seed = SlotState.IDLE, None
        return [Event(EventKind.DONE, record.seed, record, worker=slot.name)]

    def _lost(self, slot: _ActorSlot, err: Exception) -> Event:
        state, seed, elapsed = slot.state, slot.seed, time.monotonic() - slot.since
        first_line = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        self._replace(slot)
        if state is SlotState.LOADING:
            return Event(EventKind.LOAD_FAILED, reason=f"{slot.name} died while loading: {first_line}", worker=slot.name)
        return Event(EventKind.LOST, seed, reason=f"its Ray worker {slot.name} was lost ({first_line})",
                     wall_seconds=elapsed, worker=slot.name)

    def close(self) -> None:
        for slot in self.slots:
            if slot.state is SlotState.IDLE:
                try:
                    self.ray.get(slot.actor.close.remote(), timeout=30)
                except Exception:  # an actor already gone has nothing to close
                    pass
            self.ray.kill(slot.actor, no_restart=True)
        if self.owns_ray:
            self.ray.shutdown()
