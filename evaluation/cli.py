"""``objective eval``: its arguments and the command, added to ``objective`` through the
``objective.commands`` entry-point group (``COMMAND``). Loaded whenever ``objective`` builds its
parser, so only argparse and the CLI's argument types are imported at module level."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from runtime.app.cli import add_protective_stop_arguments, parse_set, positive_float, protective_stop_inputs
from runtime.io.bus import DEFAULT_POLICY_LATENCY
from runtime.app.command import OBJECTIVE_FILE_HELP, POLICY_HELP, Command

HELP = "run an Objective over many seeded episodes and report its success rate"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (HELP + ". Episodes are `objective run --seed S+i`; DIR gets episodes.jsonl (appended as "
                     "episodes finish), summary.json and report.html; running the same command again resumes.")
    p.add_argument("file", type=Path, help=OBJECTIVE_FILE_HELP)
    p.add_argument("--episodes", type=int, required=True, metavar="N", help="episodes to run: seeds S .. S+N-1")
    p.add_argument("--seed-start", type=int, default=0, metavar="S", help="seed of the first episode (default 0)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="where the results go (resumed if it holds some)")
    p.add_argument("--workers", type=int, default=1, metavar="K", help="episodes run in parallel (default 1)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local processes (default) or Ray tasks (`make ray`); see docs/evaluation.md")
    p.add_argument("--ray-address", metavar="ADDR", help="join this Ray cluster (default: start a local one sized to --workers)")
    p.add_argument("--policy", metavar="SPEC", help=POLICY_HELP)
    p.add_argument("--policy-latency", default=None, metavar="SPEC",
                   help=f"simulated policy latency: seconds (default {DEFAULT_POLICY_LATENCY}, as objective run), lognormal:MEAN,SD, "
                        "or measured (not deterministic)")
    p.add_argument("--world", metavar="NAME", help="world for trees that need one (default: vla_sim)")
    p.add_argument("--set", action="append", type=parse_set, default=[], metavar="NAME=VALUE",
                   help="set a root blackboard entry before the first tick of every episode; repeatable")
    p.add_argument("--world-option", action="append", type=parse_set, default=[], metavar="KEY=VALUE",
                   help="an option of the world, e.g. image_size=128 (repeatable)")
    p.add_argument("--record", choices=("failures", "all", "none"), default="failures",
                   help="keep a recording (with its report) of the failed episodes (default), of all, or none")
    p.add_argument("--tree", metavar="ID", help="the BehaviorTree to run (default: main_tree_to_execute)")
    p.add_argument("--max-seconds", type=positive_float, metavar="S", help="an episode fails after S seconds of clock time")
    p.add_argument("--episode-timeout", type=positive_float, default=None, metavar="S",
                   help="wall-clock seconds before a hung episode's worker is stopped (default 600)")
    p.add_argument("--retries", type=int, default=None, metavar="N",
                   help="times an episode whose worker died is run again on a fresh worker (default 1)")
    p.add_argument("--json", action="store_true", help="print summary.json as the last line of stdout")
    p.add_argument("--path", action="append", type=Path, default=[], metavar="DIR",
                   help="another directory of *.xml to find SubTrees in (after objectives/); repeatable")
    p.add_argument("--objectives-dir", type=Path, default=None, metavar="DIR",
                   help="the library searched first for SubTrees (default: the project's objectives/)")
    add_protective_stop_arguments(p)
    p.set_defaults(protective_stop=None)  # None: not given (listened for only where rclpy imports)


def stop_listener(args: argparse.Namespace) -> Any:
    """The node that listens for the protective stop in this process (``runtime.app.stop_listener``),
    or None: ``--protective-stop ''`` and no deadman, or no rclpy (said only when a stop input was
    given: by default an evaluation does not need ROS 2). ObjectiveError for a name ROS 2 refuses."""
    from runtime.app.protective_stop import SharedStop

    from .executors import CONTEXT

    inputs = protective_stop_inputs(args)
    inputs.check()
    if not (inputs.topic or inputs.deadman_topic):
        return None
    try:
        from runtime.app.stop_listener import StopListener
    except ImportError as err:
        if args.protective_stop is not None or args.deadman_topic:
            print(f"warning: the protective stop is not listened for: {err.name or err} does not import "
                  "(the [ros] extra or a sourced ROS 2)", file=sys.stderr)
        return None
    return StopListener(inputs, SharedStop(CONTEXT))


def config_from_args(args: argparse.Namespace) -> Any:
    from .config import (
        DEFAULT_EPISODE_TIMEOUT_S, DEFAULT_RETRIES, EvalConfig, ExecutorKind, RecordMode, WorkerSpec,
    )
    from .policies import parse_policy

    spec = WorkerSpec(
        objective=args.file.resolve(), tree=args.tree, search_paths=tuple(p.resolve() for p in args.path),
        objectives_dir=args.objectives_dir.resolve() if args.objectives_dir else None, world=args.world,
        policy=parse_policy(args.policy), policy_latency=args.policy_latency or DEFAULT_POLICY_LATENCY,
        sets=tuple(args.set), world_options=tuple(args.world_option), max_seconds=args.max_seconds, record=RecordMode(args.record),
    )
    return EvalConfig(
        spec=spec, out=args.out, episodes=args.episodes, seed_start=args.seed_start, workers=args.workers,
        executor=ExecutorKind(args.executor), ray_address=args.ray_address,
        episode_timeout_s=args.episode_timeout or DEFAULT_EPISODE_TIMEOUT_S,
        retries=DEFAULT_RETRIES if args.retries is None else args.retries,
    )


def summary_lines(summary: dict[str, Any], out: Path) -> list[str]:
    """What a person reads on stderr when the evaluation ends."""
    rate = summary["success_rate"]
    low, high = summary["success_rate_ci95"]
    rate_text = "n/a" if rate is None else f"{100 * rate:.1f} %, 95 % interval {100 * low:.1f}-{100 * high:.1f} %"
    done = f"{summary['episodes']} episodes" + ("" if summary["complete"] else f" of {summary['requested']} (incomplete: run again to resume)")
    lines = [f"{done}: {summary['successes']} successes ({rate_text}), {summary['failures']} failures, {summary['errors']} errors"]
    for group in summary["failure_groups"][:5]:
        node = f"'{group['failing_node']}': " if group["failing_node"] else ""
        example = f": {group['example']}" if group["example"] and group["example"] != group["reason"] else ""
        lines.append(f"  {group['count']:>4} x {group['status']} {node}{group['reason']}{example}")
    if summary.get("protective_stop"):
        lines.append(f"stopped by the protective stop ({summary['protective_stop']}): no episode started after it, "
                     "the running ones ended FAILURE; run the same command again to run the rest")
    if summary.get("stopped"):
        lines.append(f"stopped after seed {summary['stopped']['seed']}: a mistake of the setup, found before the first "
                     "tick, that every seed would repeat: fix it, then evaluate again")
    lines.append(f"results in {out}/ (episodes.jsonl, summary.json, report.html)")
    return lines


def cmd_eval(args: argparse.Namespace, registry: Any) -> int:
    from runtime.io.interrupt import StopRequest, stop_on_signals

    from .evaluate import evaluate
    from .progress import ProgressBar

    config = config_from_args(args)
    bar: list[ProgressBar] = []

    def progress(resumed: list[Any]) -> ProgressBar:
        bar.append(ProgressBar(sys.stderr, config.episodes, resumed))
        return bar[0]

    stop = StopRequest(urgent=True)  # SIGINT/SIGTERM stop it at once: the finished episodes are kept and summarised
    listener = stop_listener(args)
    try:
        with stop_on_signals(stop):
            outcome = evaluate(config, registry, progress if sys.stderr.isatty() else None, stop, listener)
    finally:
        if listener is not None:
            listener.close()
        if bar:
            bar[0].clear()
    if outcome.interrupted:
        print(f"interrupted by {outcome.summary['interrupted']}: the finished episodes are kept; "
              "run the same command again to resume", file=sys.stderr)
    for line in summary_lines(outcome.summary, config.out):
        print(line, file=sys.stderr)
    if args.json:
        print(json.dumps(outcome.summary, default=str))
    return outcome.exit_code


COMMAND = Command(HELP, add_arguments, cmd_eval)
