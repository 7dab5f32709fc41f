"""``EpisodeWorker``: runs episodes one after another, paying for what is expensive once.

Created in each worker (a local process or a Ray actor), it loads the registry (every behavior
module), the world (the robot and planning models, a MuJoCo model and renderer) and the policy
(a LeRobot checkpoint) once, in ``warm_up``. Each episode then gets a new clock, bus and tree
and the same world put back to the episode's seed (``begin_episode``), so a seed gives the same
episode as a fresh ``objective run --seed`` would: same layout, time 0, controllers and planning
scene built anew, latency model seeded with the seed.

A world without ``begin_episode`` (a user's world) is created anew for every episode, serving
its own policy as ``objective run`` does.
"""
from __future__ import annotations

import logging
import shutil
import time
import traceback
from pathlib import Path
from typing import Any

from runtime.io.bus import FixedLatency, SimulatedLatency, capability
from runtime.errors import INTERNAL, InternalError, ObjectiveError, error_kind
from runtime.tree import node_info
from runtime.tree.loader import load_tree
from runtime.app.protective_stop import ProtectiveStop, SharedStop
from runtime.tree.registry import Registry
from runtime.tree.registry import default_world_name
from runtime.app.runner import RunOptions, RunResult, make_context, run_tree
from runtime.app.world import KeepsEpisodes, create_world

from .config import WorkerSpec
from .episode import EpisodeRecord
from .policies import PolicyHost

RECORDINGS_DIR = "recordings"
_log = logging.getLogger("objective")


def recording_name(seed: int) -> str:
    return f"seed-{seed}"


def _render(worker: Any, directory: Path) -> dict[str, Any]:
    """Render the report of the finished recording in ``directory``; what the episode's record
    notes of it: ``recording_errors`` (the artifacts that failed), ``recording_incomplete`` (why
    the recording is not whole: a full disk).

    The recording worker renders it once it has written every file of the recording (it takes
    the request after the recording's end, ``RENDER_TIMEOUT`` bounds the wait), so the report
    never reads a ``run.mcap`` still being written. A recording that cannot be read is noted
    with the episode: the episode's own outcome stands.
    """
    try:
        report = worker.render(directory)
    except ObjectiveError as err:
        return {"recording_errors": {"recording": str(err)}}
    notes: dict[str, Any] = {}
    if report.errors:
        notes["recording_errors"] = {k: str(v) for k, v in report.errors.items()}
    if report.partial:
        notes["recording_incomplete"] = "; ".join(report.partial)
    return notes


class KeptWorld:
    """The world of one episode as the runner sees it: the worker's world, put back to the
    episode's seed when the run starts, and left open when the run ends (the worker closes it)."""

    def __init__(self, world: Any, policy: PolicyHost, seed: int, latency: str) -> None:
        self.world, self.policy, self.seed, self.latency = world, policy, seed, latency
        self.name = world.name

    def start(self, context: Any) -> None:
        self.world.begin_episode(self.seed)
        self.world.start(context)
        self.policy.serve(context.bus, self.seed, self.latency)

    def step_to(self, t: float) -> None:
        self.world.step_to(t)

    def reset(self, seed: int) -> None:
        self.world.reset(seed)

    def summary(self) -> dict[str, Any]:
        summary: dict[str, Any] = self.world.summary()
        return summary

    def close(self) -> None:
        """Nothing: the world outlives the episode."""


class EpisodeWorker:
    def __init__(self, spec: WorkerSpec, name: str = "", recordings: Path | None = None,
                 stop: SharedStop | None = None) -> None:
        self.spec = spec
        self.name = name
        self.recordings = recordings
        """Where kept recordings go (``DIR/recordings`` locally; a scratch folder on a Ray node)."""
        self.stop = stop
        """The protective stop ``objective eval`` heard and forwards: every episode's guard asks it."""
        self.registry: Registry | None = None
        self.world: Any = None
        self.policy: PolicyHost | None = None
        self.needs_world = False

    # -- lifecycle ---
    def warm_up(self) -> dict[str, Any]:
        """Load everything once; ObjectiveError for bad input (the Objective, the world, the policy)."""
        started = time.monotonic()
        self.registry = Registry.from_entry_points()
        options = self._options(0)
        loaded = load_tree(self.spec.objective, self.registry, make_context(options), self.spec.tree,
                           self.spec.search_paths, self.spec.objectives_dir)
        self.needs_world = any(node_info.needs_world(type(n)) for n in loaded.root.iterate())
        if self.needs_world:
            world = create_world(self.spec.world or default_world_name(), self._world_options(0, "none"))
            if isinstance(world, KeepsEpisodes):
                self.world = world
                try:
                    self.policy = PolicyHost(self.spec.policy, world)
                except ImportError as err:
                    raise ObjectiveError(f"--policy {self.spec.policy.text}: {err} (the LeRobot extra: `make lerobot` in a checkout, or pip install 'objective-runtime[lerobot]')") from None
                except (ObjectiveError, OSError) as err:
                    raise ObjectiveError(f"--policy {self.spec.policy.text}: {err}") from None
            else:
                world.close()
        return {"worker": self.name, "load_seconds": round(time.monotonic() - started, 3)}

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
            self.world = None

    # -- episodes ---
    def run(self, seed: int) -> EpisodeRecord:
        """One episode; an exception of the run becomes an ERROR record with its reason."""
        started = time.monotonic()
        _log.info("%s: seed %d started", self.name, seed)  # in logs/worker-N.log: which episode a worker runs
        try:
            record = self._run(seed)
        except (ObjectiveError, InternalError) as err:
            record = EpisodeRecord.error(seed, str(err), time.monotonic() - started, kind=error_kind(err))
        except Exception as err:  # a behavior or world raised: the episode is an error, the evaluation goes on
            where = traceback.extract_tb(err.__traceback__)[-1]
            record = EpisodeRecord.error(
                seed, f"{type(err).__name__}: {err} (at {Path(where.filename).name}:{where.lineno})",
                time.monotonic() - started, kind=INTERNAL,
            )
        record.worker = self.name
        return record

    def _run(self, seed: int) -> EpisodeRecord:
        assert self.registry is not None, "warm_up() first"
        options = self._options(seed)
        context = make_context(options)
        modelled = capability(context.bus, SimulatedLatency)
        if self.spec.policy_latency.strip().lower() != "measured" and modelled is not None:
            # Every other service (switching controllers, ...) answers on the next tick, as it does
            # on an idle machine, instead of after the measured wall time: that would make the
            # episode depend on the machine's load.
            modelled.default_latency = FixedLatency(0.0)
        loaded = load_tree(self.spec.objective, self.registry, context, self.spec.tree,
                           self.spec.search_paths, self.spec.objectives_dir)
        world: Any = None
        if self.needs_world:
            if self.world is not None and self.policy is not None:
                world = KeptWorld(self.world, self.policy, seed, self.spec.policy_latency)
            else:
                world = create_world(self.spec.world or default_world_name(), self._world_options(seed, self.spec.policy.text))
        if self.recordings is None or self.spec.record.value == "none":
            return EpisodeRecord.from_result(seed, run_tree(loaded, context, options, world=world, guard=self._guard(context, options)))
        return self._run_recorded(seed, loaded, context, options, world)

    def _run_recorded(self, seed: int, loaded: Any, context: Any, options: RunOptions, world: Any) -> EpisodeRecord:
        """The run with a Recorder on its bus; kept (with its report) or deleted per ``--record``."""
        from recording import Recorder

        assert self.recordings is not None
        final = self.recordings / recording_name(seed)
        scratch = self.recordings / f".partial-{recording_name(seed)}"
        shutil.rmtree(scratch, ignore_errors=True)
        recorder = Recorder(scratch, context, list(loaded.root.iterate()), loaded)
        worker = recorder.worker  # writes the recording, then renders its report
        try:
            try:
                result: RunResult = run_tree(loaded, context, options, world=world, guard=self._guard(context, options))
            except BaseException:
                recorder.close()
                worker.close()
                shutil.rmtree(scratch, ignore_errors=True)
                raise
            recorder.finish(result.to_json())
            record = EpisodeRecord.from_result(seed, result)
            if not self.spec.record.keeps(result.status):
                worker.close()  # stopped before its files are removed
                shutil.rmtree(scratch, ignore_errors=True)
                return record
            record.run.update(_render(worker, scratch))
        finally:
            worker.close()
        shutil.rmtree(final, ignore_errors=True)
        scratch.rename(final)
        record.recording = f"{RECORDINGS_DIR}/{final.name}"
        return record

    def _guard(self, context: Any, options: RunOptions) -> ProtectiveStop | None:
        """The episode's protective stop: its own bus's inputs (as ``run_tree`` makes them) and the
        forwarded stop; None (``run_tree``'s own) when nothing is forwarded."""
        if self.stop is None or options.protective_stop is None:
            return None
        guard = ProtectiveStop(options.protective_stop, forwarded=self.stop.reason)
        guard.listen(context.bus)
        return guard

    # -- options ---
    def _options(self, seed: int) -> RunOptions:
        return RunOptions(
            seed=seed, world=self.spec.world, sets=dict(self.spec.sets), policy_latency=self.spec.policy_latency,
            max_seconds=self.spec.max_seconds, world_options={**dict(self.spec.world_options), "policy": self.spec.policy.text},
        )

    def _world_options(self, seed: int, policy: str) -> dict[str, Any]:
        return {"seed": seed, "realtime": False, "policy_latency": self.spec.policy_latency, "record_dir": None,
                **dict(self.spec.world_options), "policy": policy}
