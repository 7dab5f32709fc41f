"""Camera frames rendered and published on a thread of their own (on ROS 2).

On a bus that pushes topics to readers elsewhere (``Bus.produces_on_read`` False), a frame costs
whether or not it is read, and a frame set of three cameras takes tens of milliseconds on a CPU
renderer: more than a 10 ms tick has to spare. So the world does not render in its tick. After
each world step the owner offers the cell's state (``Cell.snapshot()``, a copy) when a set is due
and someone subscribes; this thread renders that copy (``Cell.render_snapshot``; MuJoCo renders
without holding the GIL) and publishes the frames stamped with the snapshot's time. While the
thread is still busy with one set, a due set is skipped rather than queued: what a subscriber
gets is always the newest frame the machine could render, at most ``rate_hz`` sets a second.
"""
from __future__ import annotations

import logging
import threading
from typing import Any, Callable

from sensor_msgs.msg import Image

from runtime.io.clock import next_due

STOP_WAIT_S = 5.0
log = logging.getLogger("objective")


class CameraThread:
    """Renders ``cell``'s cameras off the owner's thread and publishes each on its publisher."""

    def __init__(self, cell: Any, publishers: dict[str, Any], rate_hz: float, to_image: Callable[[str, Any, float], Image]) -> None:
        if not rate_hz > 0:
            raise ValueError(f"camera_rate_hz must be > 0, got {rate_hz}")
        self.cell = cell
        self.publishers = publishers
        self.period_s = 1.0 / rate_hz
        self.to_image = to_image
        """``to_image(camera, pixels, t)``: the message to publish for a rendered frame."""
        self.sets_published = 0
        self.sets_skipped = 0
        """Due sets dropped because the thread was still rendering the previous one."""
        self._due_s = 0.0
        self._pending: tuple[Any, float] | None = None
        self._wake = threading.Condition()
        self._busy = False
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="camera frames", daemon=True)
        self._thread.start()

    def offer(self, t: float) -> None:
        """After a world step at cell time ``t`` (owner's thread): hand over a snapshot when a set is due."""
        if t < self._due_s - 1e-9 or not any(p.subscriber_count() for p in self.publishers.values()):
            return
        self._due_s = next_due(self._due_s, self.period_s, t)
        with self._wake:
            if self._busy or self._pending is not None:
                self.sets_skipped += 1
                return
            self._pending = (self.cell.snapshot(), t)
            self._wake.notify()

    def close(self) -> None:
        with self._wake:
            self._closing = True
            self._wake.notify()
        self._thread.join(STOP_WAIT_S)

    def _run(self) -> None:
        try:
            while True:
                with self._wake:
                    while self._pending is None and not self._closing:
                        self._wake.wait()
                    if self._closing:
                        return
                    pending, self._pending = self._pending, None
                    assert pending is not None  # the wait ends with one (or closing)
                    snapshot, t = pending
                    self._busy = True
                try:
                    for camera, publisher in self.publishers.items():
                        if publisher.subscriber_count():
                            publisher.publish(self.to_image(camera, self.cell.render_snapshot(snapshot, camera), t))
                    self.sets_published += 1
                except Exception as err:  # the cameras stop; the robot and the run go on
                    log.warning("camera frames stopped: %s", err)
                    return
                finally:
                    with self._wake:
                        self._busy = False
        finally:
            self.cell.close_snapshot_renderer()
