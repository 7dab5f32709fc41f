"""The recording worker: a second process, started with a recorded run, that writes the
recording and renders its report, so the run itself only serializes.

``ReportWorker`` starts ``python -m recording.report.worker`` when the recorded run starts. The
run hands its messages over through the worker's stdin (``record``: a
``recording.handoff.Handoff``); the worker writes ``run.mcap``, ``events.jsonl`` and
``metadata.yaml`` and builds the report's data as messages arrive
(``recording.session``), encoding each camera frame into ``cameras.mp4`` as its policy
request arrives (``VideoEncoder``), while it imports the report's modules on a thread beside.
When the run is over, ``render`` asks for the report: the worker closes the video, draws the
plots and the tree as SVG from the data it already holds and answers one JSON line with the
files written and the artifacts that failed.
``render`` of a directory the worker did not record reads it back from its files.

The worker reads its stdin on a thread from its first instant (``_Drain``) and only then imports
what it needs (numpy, rclpy, mcap: a few tenths of a second), so a run that fills the pipe
meanwhile does not wait; this module imports nothing heavy at its top for that reason.

Signals are the run's business: the worker runs in a process group of its own, so Ctrl-C at the
terminal reaches only the run (which stops the worker if it must), and it starts with SIGINT
blocked (and then ignored), so one sent to it directly does nothing either; it never prints a
traceback.

Nothing is lost if the worker cannot render: if it died, answers garbage or takes longer than
``timeout``, ``render`` stops it and the report is rendered in this process from the files. If
the run's process dies, the worker reads end-of-file, writes what it received (the recording
stays partial, as a killed run leaves it) and exits without rendering anything. If the worker
dies while recording, see ``recording.recorder``.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

from runtime.errors import ObjectiveError
from ..files import VIDEO_FILE
from . import Report, log_errors, render_report

if TYPE_CHECKING:
    from ..handoff import Handoff

RENDER_TIMEOUT = 600.0
"""Seconds the worker may take to render a report (a long run's video is the slow part)."""
READ_AHEAD_BYTES = 1 << 20
"""Most the worker reads from the run's pipe ahead of what it has written (``_Drain``); with
the pipe itself (``recording.handoff.PIPE_BYTES``) what a worker that dies can lose."""


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
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        try:
            with _sigint_blocked():  # the worker inherits the mask: deaf to SIGINT from its first instruction
                self.process = subprocess.Popen(
                    [sys.executable, "-m", "recording.report.worker"],
                    stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                    process_group=0,  # the terminal's Ctrl-C goes to the run, not to its worker
                )
        except OSError:
            self.process = None  # rendered in process instead

    def record(self, directory: Path | str, clock_origin_ns: int) -> Handoff | None:
        """Where the run sends its recording of ``directory`` (None without a worker)."""
        from ..handoff import Handoff

        if self.process is None or self.process.stdin is None:
            return None
        return Handoff(self.process.stdin.fileno(), str(directory), clock_origin_ns)

    def exit_status(self) -> int | None:
        """The worker's exit status once it has exited (for the run's warning when it is lost)."""
        return self.process.poll() if self.process is not None else None

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

    def close(self, finish_s: float = 0.0) -> None:
        """Stop the worker if it is still there (a run that ended without a report): it first gets
        ``finish_s`` seconds to write what it received and exit (end of file: no report)."""
        process, self.process = self.process, None
        if process is None or process.poll() is not None:
            return
        if finish_s > 0 and process.stdin is not None:
            with contextlib.suppress(OSError):
                process.stdin.close()
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(finish_s)
        if process.poll() is None:
            process.kill()
        process.wait()
        for pipe in (process.stdin, process.stdout):
            if pipe is not None:
                with contextlib.suppress(OSError):
                    pipe.close()

    def _ask(self, directory: Path, timeout: float) -> dict[str, Any] | None:
        from ..handoff import Frame, WorkerLost, json_frame, write_all

        process, self.process = self.process, None
        if process is None:
            return None
        try:
            assert process.stdin is not None
            write_all(process.stdin.fileno(), json_frame(Frame.RENDER, {"directory": str(directory)}))
            out, _ = process.communicate(timeout=timeout)
            answer = json.loads(out.strip().splitlines()[-1]) if process.returncode == 0 and out.strip() else None
        except (subprocess.TimeoutExpired, OSError, ValueError, WorkerLost):
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


def _import_report_libraries(failed: list[BaseException]) -> None:
    """Everything the report imports, while the recording arrives (on a thread: imageio is slow)."""
    try:
        from . import html, plots, tree_svg, video  # noqa: F401

        import imageio.v2  # noqa: F401
    except BaseException as err:  # the run renders in its own process and reports what is missing there
        failed.append(err)


def _answer(directory: str, recording: Any, video: Callable[[], Path] | None) -> dict[str, Any]:
    try:
        report = render_report(directory, recording=recording, video=video)
        return {"files": {k: str(v) for k, v in report.files.items()}, "errors": report.errors, "partial": report.partial}
    except Exception as err:
        return {"failed": str(err) if isinstance(err, ObjectiveError) else f"{type(err).__name__}: {err}"}


class _Drain:
    """Reads the run's pipe on a thread from the worker's first instant: its imports take a few
    tenths of a second, during which a run that filled the pipe would wait. Holds at most
    ``READ_AHEAD_BYTES`` read ahead of what the worker has taken (``read``)."""

    def __init__(self, fd: int, limit: int = READ_AHEAD_BYTES) -> None:
        self._fd = fd
        self._limit = limit
        self._chunks: list[bytes] = []
        self._held = 0
        self._ended = False
        self._changed = threading.Condition()
        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self) -> None:
        while True:
            with self._changed:
                self._changed.wait_for(lambda: self._held < self._limit)
            try:
                data = os.read(self._fd, self._limit)
            except InterruptedError:
                continue
            except OSError:
                data = b""
            with self._changed:
                self._chunks.append(data)
                self._held += len(data)
                self._changed.notify_all()
            if not data:
                return

    def read(self) -> bytes:
        """All that arrived since the last call (waits for something); ``b""`` at end of file."""
        with self._changed:
            self._changed.wait_for(lambda: self._chunks or self._ended)
            data = b"".join(self._chunks)
            self._ended = self._ended or self._chunks[-1:] == [b""]
            self._chunks.clear()
            self._held = 0
            self._changed.notify_all()
        return data


def main() -> int | None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run decides when the worker stops
    try:
        drain = _Drain(sys.stdin.fileno())  # before the imports: the run must not wait for them
        return _serve(drain.read)
    except Exception:  # the run notices (WorkerLost, or no answer) and does the work itself
        return 1


def _serve(read: Callable[[], bytes]) -> int | None:
    from ..handoff import Frame, read_frames
    from ..session import RecordingSession
    from .video import VideoEncoder

    failed: list[BaseException] = []
    imports = threading.Thread(target=_import_report_libraries, args=(failed,), daemon=True)
    imports.start()
    session: RecordingSession | None = None
    encoder: VideoEncoder | None = None
    for kind, payload in read_frames(read):
        if kind is None:  # all that has arrived is taken: to the files
            if session is not None and not session.ended:
                session.flush_if_due()
        elif kind is Frame.START:
            start = json.loads(payload)
            session = RecordingSession(start["directory"], int(start["clock_origin_ns"]))
            encoder = VideoEncoder(session.directory / VIDEO_FILE)
            session.contents.on_frame = encoder.add
        elif kind is Frame.RENDER:
            imports.join()
            if failed:
                return 1
            directory = json.loads(payload)["directory"]
            mine = session is not None and session.ended and Path(directory) == session.directory
            if encoder is not None and not mine:
                encoder.discard()
            answer = _answer(directory, session.recording if mine and session is not None else None, encoder.close if mine and encoder else None)
            try:
                print(json.dumps(answer), flush=True)
            except OSError:  # the run stopped listening (it was interrupted): nothing to tell
                pass
            os._exit(0)  # every file is closed; skip the interpreter's teardown, which the run waits for
        elif session is not None:
            session.take(kind, payload)
            if session.ended and encoder is not None:
                encoder.close_soon()  # every frame is in: ffmpeg finishes while the rest is drawn
    if session is not None and not session.ended:
        session.abandon()  # the run died: keep what it sent
    if encoder is not None:
        encoder.discard()  # no report without a run: `objective report` renders the video again
    return 0


if __name__ == "__main__":
    sys.exit(main())
