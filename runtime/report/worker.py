"""Render a recorded run's report in a second process that gets ready while the run goes on.

Most of what a report costs after the run is fixed: importing matplotlib and imageio, then
drawing. ``ReportWorker`` starts ``python -m runtime.report.worker`` when the recorded run starts;
that process imports everything the report needs (on the other core, while the run ticks) and
waits for one line on stdin. When the run is over and ``run.mcap`` is closed, ``render`` sends
the directory, the worker renders the report (``render_report(..., parallel=True)``: the joint
plot in a forked process beside the rest) and answers one JSON line with the files written and
the artifacts that failed.

Signals are the run's business: the worker runs in a process group of its own, so Ctrl-C at the
terminal reaches only the run (which stops the worker if it must), and it starts with SIGINT
blocked (and then ignored), so one sent to it directly does nothing either; it never prints a
traceback.

Nothing is lost if the worker cannot help: if it died, answers garbage or takes longer than
``timeout``, ``render`` stops it and the report is rendered in this process as before. If this
process dies, the worker reads end-of-file and exits without rendering anything.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterator

from ..errors import ObjectiveError
from . import Report, log_errors, render_report

RENDER_TIMEOUT = 600.0
"""Seconds the worker may take to render a report (a long run's video is the slow part)."""


@contextlib.contextmanager
def _sigint_blocked() -> Iterator[None]:
    """Block SIGINT in this thread while inside: one arriving meanwhile is delivered on the way out."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class ReportWorker:
    """One report, rendered by a process started before it is needed (see the module doc)."""

    def __init__(self) -> None:
        self.process: subprocess.Popen[str] | None = None

    def start(self) -> None:
        try:
            with _sigint_blocked():  # the worker inherits the mask: deaf to SIGINT from its first instruction
                self.process = subprocess.Popen(
                    [sys.executable, "-m", "runtime.report.worker"],
                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                    process_group=0,  # the terminal's Ctrl-C goes to the run, not to its worker
                )
        except OSError:
            self.process = None  # rendered in process instead

    def render(self, directory: Path | str, logger: logging.Logger | None = None, timeout: float = RENDER_TIMEOUT) -> Report:
        """The report of ``directory``, from the worker if it can, else rendered here."""
        directory = Path(directory)
        answer = self._ask(directory, timeout)
        if answer is None:
            return render_report(directory, logger)
        if "failed" in answer:  # the recording itself cannot be read: rendering here would fail alike
            raise ObjectiveError(str(answer["failed"]))
        report = Report(directory, {k: Path(v) for k, v in answer["files"].items()}, dict(answer["errors"]),
                        [str(reason) for reason in answer.get("partial", [])])
        log_errors(report, logger)
        return report

    def close(self) -> None:
        """Stop the worker if it is still there (a run that ended without a report)."""
        process, self.process = self.process, None
        if process is not None and process.poll() is None:
            process.kill()
            process.communicate()

    def _ask(self, directory: Path, timeout: float) -> dict[str, Any] | None:
        process, self.process = self.process, None
        if process is None:
            return None
        try:
            out, _ = process.communicate(json.dumps({"directory": str(directory)}) + "\n", timeout=timeout)
            answer = json.loads(out.strip().splitlines()[-1]) if process.returncode == 0 and out.strip() else None
        except (subprocess.TimeoutExpired, OSError, ValueError):
            process.kill()
            process.communicate()
            return None
        except BaseException:  # interrupted while waiting: the worker has nobody to answer
            process.kill()
            process.wait()
            raise
        if isinstance(answer, dict) and "failed" in answer:
            return answer
        if not isinstance(answer, dict) or not isinstance(answer.get("files"), dict) or not isinstance(answer.get("errors"), dict):
            return None
        return answer


def main() -> int | None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run decides when the worker stops
    try:  # everything the report imports, before the directory arrives
        from . import html, plots, tree_svg, video  # noqa: F401

        import imageio.v2  # noqa: F401
        import matplotlib.backends.backend_agg  # noqa: F401
        import sensor_msgs.msg  # noqa: F401  (the recording's messages are read back with these)
        import trajectory_msgs.msg  # noqa: F401
    except Exception:
        return 1  # the run renders in its own process and reports what is missing there
    line = sys.stdin.readline()
    if not line.strip():
        return 0  # the run ended without a report (or its process died)
    try:
        report = render_report(json.loads(line)["directory"], parallel=True)
        answer = {"files": {k: str(v) for k, v in report.files.items()}, "errors": report.errors, "partial": report.partial}
    except Exception as err:
        answer = {"failed": str(err) if isinstance(err, ObjectiveError) else f"{type(err).__name__}: {err}"}
    try:
        print(json.dumps(answer), flush=True)
    except OSError:  # the run stopped listening (it was interrupted): nothing to tell
        pass
    os._exit(0)  # every file is closed; skip the interpreter's teardown, which the run waits for


if __name__ == "__main__":
    sys.exit(main())
