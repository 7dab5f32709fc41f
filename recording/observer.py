"""The recording as a run observer (``runtime.app.observer``): ``objective run --record DIR`` / ``--live``.

``attach`` puts a ``Recorder`` on the run's bus (into ``options.record_dir`` and/or served live);
``finished`` writes the summary and renders the report into the directory; ``aborted`` writes
what ended a run that never got to a result. A signal while the report renders stops the
rendering; ``objective report DIR`` renders it later.
"""
from __future__ import annotations

from importlib.util import find_spec
from pathlib import Path
from typing import Any

from runtime.errors import ObjectiveError
from runtime.extras import missing_module_message
from runtime.io.interrupt import StopRequest, held_back
from runtime.tree.behavior import RunContext
from runtime.tree.loader import LoadedTree
from runtime.app.observer import RunObserver
from runtime.app.runner import RunEnd, RunOptions, RunResult

NEEDED_MODULES = ("mcap", "mcap_ros2")
"""What a recording needs beyond the core (the ``[record]`` extra); ``--live`` needs foxglove too."""
RECORDING_END_TIMEOUT_S = 30.0
"""Wall-clock bound on the recording worker writing the end of an interrupted run's recording
(what it received, the MCAP summary section, ``metadata.yaml``); past it, it is stopped."""


def attach(loaded: LoadedTree, context: RunContext, options: RunOptions) -> "RecordingObserver | None":
    """The ``objective.run_observers`` factory: a recorder when the options ask for one."""
    if not options.observed:
        return None
    _check_installed(NEEDED_MODULES + (("foxglove",) if options.live_port is not None else ()))
    from .live import LiveOptions
    from .recorder import Recorder

    live = LiveOptions(port=options.live_port) if options.live_port is not None else None
    recorder = Recorder(options.record_dir, context, list(loaded.root.iterate()), loaded, live=live)
    if recorder.live is not None:
        context.logger.info("live view: in Foxglove, open a Foxglove WebSocket connection to %s", recorder.live.url)
    return RecordingObserver(recorder, options.record_dir, context.logger)


def _check_installed(modules: tuple[str, ...]) -> None:
    """ObjectiveError naming the extra when one of ``modules`` is not installed (nothing is imported:
    the recording worker's process imports mcap, not the run's)."""
    for module in modules:
        if find_spec(module) is None:
            raise ObjectiveError(f"--record/--live: {missing_module_message(module)}")


class RecordingObserver(RunObserver):
    """One recorded run: the recorder on its bus, then the summary and the report."""

    def __init__(self, recorder: Any, record_dir: Path | None, logger: Any) -> None:
        self.recorder = recorder
        self.record_dir = record_dir
        self.logger = logger
        self.worker = recorder.worker if record_dir is not None else None  # writes the recording, renders the report

    def aborted(self, error: BaseException, stop: StopRequest | None) -> None:
        if self.worker is None:
            self.recorder.close()
            return
        end = RunEnd.INTERRUPTED if isinstance(error, KeyboardInterrupt) else RunEnd.ERROR
        try:
            with held_back(stop):  # a signal now waits until the summary and the end are sent
                self.recorder.finish({"status": end.value, "reason": str(error) or type(error).__name__})
        finally:
            self.worker.close(RECORDING_END_TIMEOUT_S)

    def finished(self, result: RunResult, stop: StopRequest | None) -> None:
        """The summary and the end of the recording (a signal meanwhile waits), then the report. A
        recording that could not be written whole (a full disk) leaves the run's result as it is,
        with ``recording_incomplete`` saying why."""
        if self.worker is None:
            self.recorder.close()
            return
        try:
            with held_back(stop):  # a signal now waits until the summary and the end are sent
                self.recorder.finish(result.to_json())
                if stop is not None:
                    stop.urgent = True  # the run is over: a signal now stops the rendering at once
            report = self.worker.render(self.record_dir, self.logger)
            incomplete = "; ".join(report.partial) or self.recorder.incomplete
            if incomplete:  # (a full disk: the run went on, its recording stopped)
                result.extra["recording_incomplete"] = incomplete
        except KeyboardInterrupt:
            self.worker.close(RECORDING_END_TIMEOUT_S)  # it finishes the recording's files, renders nothing
            self.logger.warning("recording %s: the report was not rendered (interrupted); "
                                "`objective report %s` renders it", self.record_dir, self.record_dir)
        except Exception as err:  # the run itself is over and recorded: its result stands
            self.logger.warning("recording %s: the report could not be rendered: %s", self.record_dir, err)
        finally:
            self.worker.close()
