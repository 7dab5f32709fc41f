"""What a hostile local Groot2 client costs the tick loop: the worst tick of a paced run.

A 3 s ``--realtime`` run (100 Hz ticks, a Script writing a 2,000-element list onto the blackboard
every tick) is watched by ``--groot2``, first with no client, then with two clients asking as
fast as they can: one sends the largest blackboard request the monitor reads (64 KiB of names,
the ``MAX_REQUEST_BYTES`` cap), the other 1 MiB frames (over the cap: dropped unread, the client
reconnecting each time). Figures: the run's worst tick and p99 tick interval (``pacing``), and the
requests answered.

    .venv/bin/python benchmarks/bench_groot2_load.py [--seconds S]
"""
from __future__ import annotations

import argparse
import struct
import threading
from typing import Any

import common  # noqa: F401  (environment and sys.path first)
from common import report, rounded

import zmq

from runtime.app.groot2 import MAX_REQUEST_BYTES, Groot2Options, Groot2Server
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, run_file

XML = """<root BTCPP_format="4"><BehaviorTree ID="Main"><Parallel success_count="1" failure_count="1">
  <Wait seconds="{seconds}"/>
  <KeepRunningUntilFailure><Script code="big := '{filler}'"/></KeepRunningUntilFailure>
</Parallel></BehaviorTree></root>"""


def header(letter: str) -> bytes:
    return struct.pack("<BBI", 2, ord(letter), 1)


def hostile(port: int, stop: threading.Event, counts: dict[str, int]) -> list[threading.Thread]:
    """The two clients, started; each counts what it got."""

    def blackboards() -> None:
        context = zmq.Context()
        socket = context.socket(zmq.REQ)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.RCVTIMEO, 1000)
        socket.connect(f"tcp://127.0.0.1:{port}")
        names = (b"Main;" * (MAX_REQUEST_BYTES // 5))[: MAX_REQUEST_BYTES - 16]
        try:
            while not stop.is_set():
                socket.send_multipart([header("B"), names])
                try:
                    socket.recv_multipart()
                    counts["answered"] += 1
                except zmq.Again:
                    break
        finally:
            context.destroy(linger=0)

    def oversized() -> None:
        context = zmq.Context()
        frame = bytes(1 << 20)
        try:
            while not stop.is_set():
                socket = context.socket(zmq.REQ)
                socket.setsockopt(zmq.LINGER, 0)
                socket.connect(f"tcp://127.0.0.1:{port}")
                socket.send_multipart([header("B"), frame])
                counts["oversized"] += 1
                stop.wait(0.01)
                socket.close(0)
        finally:
            context.destroy(linger=0)

    threads = [threading.Thread(target=f, daemon=True) for f in (blackboards, oversized)]
    for thread in threads:
        thread.start()
    return threads


def run(seconds: float, clients: bool) -> dict[str, Any]:
    from pathlib import Path
    import tempfile

    counts = {"answered": 0, "oversized": 0}
    with tempfile.TemporaryDirectory() as folder, Groot2Server(Groot2Options(port=0)) as server:
        path = Path(folder) / "load.xml"
        path.write_text(XML.format(seconds=seconds, filler="x" * 2000))
        stop = threading.Event()
        threads = hostile(server.port, stop, counts) if clients else []
        try:
            result = run_file(path, Registry.from_entry_points(), RunOptions(realtime=True), observers=[server.observer()])
        finally:
            stop.set()
            for thread in threads:
                thread.join(2.0)
    pacing = result.to_json()["pacing"]
    return {"clients": "two hostile" if clients else "none", "status": result.status,
            "worst_tick_ms": rounded(pacing["worst_tick_s"] * 1000, 2),
            "interval_p99_ms": rounded(pacing["interval_p99_s"] * 1000, 2), **counts}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    rows = [run(args.seconds, False), run(args.seconds, True)]
    report("bench_groot2_load: the worst tick of a paced run with hostile Groot2 clients", rows,
           ["clients", "status", "worst_tick_ms", "interval_p99_ms", "answered", "oversized"],
           ["before the limits: two 24 MB blackboard requests gave a 390 ms worst tick"])


if __name__ == "__main__":
    main()
