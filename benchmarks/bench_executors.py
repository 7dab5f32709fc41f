"""rclpy's executors side by side: CPU per delivered message, one node spinning in a thread.

The node publishes to its own subscription from a 500 Hz timer and serves 40 idle services (a
wait set about the size of the runtime's node hosting the cell). Per executor: messages
delivered per second and the process's CPU time per message (timer, publish and delivery), over
``--seconds`` after a warm-up. Measured one after another in one process, in the order given.

    .venv/bin/python benchmarks/bench_executors.py [--seconds 3] [--executors single,multi,events]
"""
from __future__ import annotations

import argparse
import threading
import time

import common  # noqa: F401  (environment and sys.path first)
from common import report

TIMER_PERIOD_S = 0.002
IDLE_SERVICES = 40
WARMUP_S = 0.5


def make_executor(kind: str, context):
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor

    if kind == "single":
        return SingleThreadedExecutor(context=context)
    if kind == "multi":
        return MultiThreadedExecutor(num_threads=12, context=context)  # as runtime.io.ros.run
    from rclpy.experimental import EventsExecutor

    return EventsExecutor(context=context)


def measure(kind: str, seconds: float) -> dict:
    import rclpy
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(f"bench_executor_{kind}", context=context)
    delivered = [0]
    publisher = node.create_publisher(String, "/bench_executors", 10)
    node.create_subscription(String, "/bench_executors", lambda msg: delivered.__setitem__(0, delivered[0] + 1), 10)
    node.create_timer(TIMER_PERIOD_S, lambda: publisher.publish(String(data="x")))
    for i in range(IDLE_SERVICES):
        node.create_service(Trigger, f"/bench_executors_idle_{i}", lambda request, response: response)
    executor = make_executor(kind, context)
    executor.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)

    thread = threading.Thread(target=spin)
    thread.start()
    try:
        time.sleep(WARMUP_S)
        count, cpu, wall = delivered[0], time.process_time(), time.monotonic()
        time.sleep(seconds)
        count, cpu, wall = delivered[0] - count, time.process_time() - cpu, time.monotonic() - wall
    finally:
        stop.set()
        thread.join()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return {"bench": "executors", "executor": kind, "messages_per_s": round(count / wall, 1),
            "cpu_us_per_message": round(cpu / max(count, 1) * 1e6, 1), "cpu_share": round(cpu / wall, 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--executors", default="single,multi,events")
    args = parser.parse_args()
    rows = [measure(kind, args.seconds) for kind in args.executors.split(",") if kind]
    report("rclpy executors: CPU per delivered message", rows, ["executor", "messages_per_s", "cpu_us_per_message", "cpu_share"],
           notes=[f"one node: a {1 / TIMER_PERIOD_S:.0f} Hz timer publishing to its own subscription, {IDLE_SERVICES} idle services"])


if __name__ == "__main__":
    main()
