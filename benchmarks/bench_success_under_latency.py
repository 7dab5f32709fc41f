"""Task success under inference latency: a policy's success rate against the delay of each
policy call, for seven executors (the experiment of Black et al. 2025, "Real-Time Execution of
Action Chunking Flow Policies", on this cell), with the unsafe points each had the arm commanded.

Executors (``benchmarks/executors/objectives.py``: one Objective each, the same Prepare SubTree,
policy settings, total steps and stack check): ExecutePolicy with real-time chunking (``rtc``),
ExecutePolicy without it (``no_rtc``), synchronous execution (``sync``), LeRobot's async client
queue (``lerobot``), LeRobot's rollout RTC engine's queue (``lerobot_rtc``), newest-wins on the
stock JTC (``newest_wins``) and chunks published to the stock JTC with ros2_controllers'
``positions_upsampling`` (``jtc_upsampling``); the last five are the benchmark executors of
``benchmarks/executors``. Delays: ``objective eval --policy-latency``
specs, simulated on the sim clock (a number of seconds, or ``lognormal:MEAN,SD`` seeded by the
episode's seed).

Each (executor, delay) cell is one ``objective eval`` into ``DIR/<executor>/<delay>`` (the local
pool or Ray), so running the same command again resumes every cell. One row per cell: episodes,
successes, rate with its 95 % Wilson interval, median simulated seconds of the successful
episodes (``time_to_success_s``: the whole Objective, Prepare and stack check included), errors,
and the unsafe points: the ticks at which the controller commanded a state outside a joint limit
or within the padding of a collision while the executor ran (``CountUnsafeCommands``, beside
every executor), summed over the cell's episodes (``unsafe_points``), and the episodes with any
(``unsafe_episodes``).

    .venv/bin/python benchmarks/bench_success_under_latency.py --policy oracle --episodes 4 \\
        --delays 0 1 --out build/bench/success-latency --plot build/bench/success-latency.png
    .venv/bin/python benchmarks/bench_success_under_latency.py --policy lerobot:build/policies/NAME \\
        --world-option image_size=128 --tracking-weight 0.3 --total-steps 250 --out build/bench/learned
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import common  # noqa: F401  (environment and sys.path first)
from common import ROOT, median, report

from benchmarks.executors.objectives import Executor, PolicySettings, objective_xml
from evaluation.episode import EpisodeRecord, EpisodeStatus
from evaluation.stats import wilson_interval
from evaluation.store import read_episodes

DEFAULT_DELAYS = ("0", "0.1", "0.2", "0.5", "1", "2", "lognormal:0.5,0.5")
PLUGIN = ROOT / "benchmarks" / "executors" / "plugin"
COLUMNS = ("executor", "delay", "episodes", "successes", "rate", "ci95_low", "ci95_high", "time_to_success_s", "errors",
           "unsafe_points", "unsafe_episodes")


class BenchError(Exception):
    """A cell's evaluation could not run (the message says why)."""


@dataclass(frozen=True)
class Cell:
    executor: Executor
    delay: str

    @property
    def folder(self) -> str:
        return f"{self.executor.value}/{self.delay.replace(':', '-').replace(',', '_')}"


def delay_mean_s(delay: str) -> float:
    """The mean seconds of a ``--policy-latency`` spec (a number or ``lognormal:MEAN,SD``)."""
    text = delay.strip().lower()
    if text.startswith("lognormal:"):
        return float(text.split(":", 1)[1].split(",")[0])
    return float(text)


def check_delay(text: str) -> str:
    """argparse type: a fixed delay in seconds or lognormal:MEAN,SD (not ``measured``: it is not deterministic)."""
    try:
        if text.strip().lower().startswith("lognormal:"):
            mean, sd = (float(v) for v in text.split(":", 1)[1].split(","))
            ok = mean > 0 and sd >= 0
        else:
            ok = float(text) >= 0
    except ValueError:
        ok = False
    if not ok:
        raise argparse.ArgumentTypeError(f"a delay is seconds >= 0 or lognormal:MEAN,SD (e.g. lognormal:0.5,0.5), got {text!r}")
    return text


def unsafe_points(record: EpisodeRecord) -> int:
    """The unsafe points the probe counted in one episode (0 where it never ran: an episode that
    ended before the executor started)."""
    return int(record.run.get("unsafe_points", {}).get("count", 0))


def cell_row(cell: Cell, records: dict[int, EpisodeRecord], seeds: range) -> dict[str, Any]:
    """The row of one cell from its episode records (those of ``seeds``)."""
    done = [records[s] for s in seeds if s in records]
    successes = [r for r in done if r.status is EpisodeStatus.SUCCESS]
    unsafe = [unsafe_points(r) for r in done]
    low, high = wilson_interval(len(successes), len(done))
    return {
        "bench": "success_under_latency", "executor": cell.executor.value, "label": cell.executor.label,
        "delay": cell.delay, "delay_mean_s": delay_mean_s(cell.delay), "episodes": len(done), "requested": len(seeds),
        "successes": len(successes), "rate": round(len(successes) / len(done), 4) if done else None,
        "ci95_low": round(low, 4), "ci95_high": round(high, 4),
        "time_to_success_s": round(median([r.sim_seconds for r in successes]), 2) if successes else None,
        "errors": sum(r.status is EpisodeStatus.ERROR for r in done),
        "unsafe_points": sum(unsafe), "unsafe_episodes": sum(n > 0 for n in unsafe),
    }


def eval_command(args: argparse.Namespace, objective: Path, cell: Cell, out: Path) -> list[str]:
    command = [str(Path(sys.executable).with_name("objective")), "eval", str(objective), "--episodes", str(args.episodes),
               "--seed-start", str(args.seed_start), "--workers", str(args.workers), "--executor", args.executor,
               "--policy", args.policy, "--policy-latency", cell.delay, "--world", args.world, "--record", "none",
               "--out", str(out), "--json"]
    for option in args.world_option:
        command += ["--world-option", option]
    if args.max_seconds:
        command += ["--max-seconds", str(args.max_seconds)]
    return command


def plugin_environment() -> dict[str, str]:
    """This environment with the benchmark executors' plug-in and the repository on PYTHONPATH."""
    paths = [str(ROOT), str(PLUGIN), os.environ.get("PYTHONPATH", "")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in paths if p)}


def run_cell(args: argparse.Namespace, objective: Path, cell: Cell) -> dict[str, Any]:
    """Evaluate one cell (resuming its DIR) and return its row."""
    out = args.out / cell.folder
    done = subprocess.run(eval_command(args, objective, cell, out), env=plugin_environment(), stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
    if done.returncode not in (0, 1):  # 1: some episode ended ERROR, counted in the row
        tail = done.stderr.strip().splitlines()[-3:]
        raise BenchError(f"objective eval of {cell.executor.value} at delay {cell.delay} exited {done.returncode}: " + " / ".join(tail))
    records, _ = read_episodes(out / "episodes.jsonl")
    return cell_row(cell, records, range(args.seed_start, args.seed_start + args.episodes))


def policy_label(spec: str) -> str:
    """A ``--policy`` as titles show it: a checkpoint or a recording by its own name
    (``lerobot:NAME``, ``replay:NAME``), any other spec as it is."""
    kind, _, where = spec.partition(":")
    return f"{kind}:{Path(where).name}" if kind in ("lerobot", "replay") else spec


def rate_axis(rows: Sequence[dict[str, Any]]) -> tuple[float, float]:
    """The plot's success-rate range: all of 0-1, unless every interval ends below a quarter;
    then the rates would sit on the axis, so it ends just above the highest interval."""
    top = max([r["ci95_high"] for r in rows if r["rate"] is not None] + [0.0])
    return (-0.02, 1.02) if top > 0.25 else (-0.02, 1.2 * max(top, 0.05))


def plot(rows: Sequence[dict[str, Any]], path: Path, title: str) -> None:
    """Success rate against the mean delay, one line per executor over the fixed delays with
    its 95 % interval as a band; lognormal delays as open markers at their mean. Each executor is
    drawn a little to the side of the others, so that equal rates stay visible."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    span = max([r["delay_mean_s"] for r in rows] + [0.1])
    for number, executor in enumerate(Executor):
        mine = [r for r in rows if r["executor"] == executor.value and r["rate"] is not None]
        fixed = sorted((r for r in mine if not r["delay"].startswith("lognormal")), key=lambda r: r["delay_mean_s"])
        shift = (number - (len(Executor) - 1) / 2) * 0.008 * span  # side by side, so that equal rates do not hide each other
        color = None
        if fixed:
            x = [r["delay_mean_s"] + shift for r in fixed]
            (line,) = ax.plot(x, [r["rate"] for r in fixed], marker="o", label=executor.label)
            color = line.get_color()
            ax.fill_between(x, [r["ci95_low"] for r in fixed], [r["ci95_high"] for r in fixed], color=color, alpha=0.15)
        for r in (r for r in mine if r["delay"].startswith("lognormal")):
            ax.errorbar([r["delay_mean_s"] + shift], [r["rate"]], yerr=[[r["rate"] - r["ci95_low"]], [r["ci95_high"] - r["rate"]]],
                        fmt="s", mfc="none", color=color, capsize=3, label=None if fixed else executor.label)
    ax.set_xlabel("policy call delay, s (open squares: lognormal, at its mean; executors drawn slightly apart)")
    ax.set_ylabel("success rate (95 % Wilson interval)")
    ax.set_ylim(*rate_axis(rows))
    ax.set_title("\n".join(textwrap.wrap(title, 95)), fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="oracle", help="any --policy of objective eval (default oracle)")
    p.add_argument("--episodes", type=int, default=50, help="episodes per cell (default 50)")
    p.add_argument("--seed-start", type=int, default=100, help="first seed (default 100: held out from the demonstrations)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="objective eval's executor")
    p.add_argument("--delays", nargs="+", type=check_delay, default=list(DEFAULT_DELAYS), metavar="DELAY",
                   help=f"policy call delays: seconds or lognormal:MEAN,SD (default {' '.join(DEFAULT_DELAYS)})")
    p.add_argument("--executors", nargs="+", choices=[e.value for e in Executor], default=[e.value for e in Executor])
    p.add_argument("--out", type=Path, default=ROOT / "build" / "bench" / "success-under-latency", metavar="DIR",
                   help="one objective eval DIR per cell, resumed when run again (default build/bench/success-under-latency)")
    p.add_argument("--plot", type=Path, metavar="FILE", help="write the success-vs-delay plot here (PNG, SVG, PDF)")
    p.add_argument("--world", default="vla_sim")
    p.add_argument("--world-option", action="append", default=[], metavar="KEY=VALUE", help="as objective eval's (repeatable)")
    p.add_argument("--total-steps", type=int, default=PolicySettings.total_action_steps, help="total_action_steps of every executor")
    p.add_argument("--tracking-weight", type=float, default=PolicySettings.policy_tracking_weight,
                   help="policy_tracking_weight (ExecutePolicy and the synchronous executor smooth with it)")
    p.add_argument("--max-seconds", type=float, help="an episode fails after this many seconds of clock time")
    args = p.parse_args(argv)
    if args.episodes < 1 or args.workers < 1:
        p.error("--episodes and --workers must be at least 1")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    settings = PolicySettings(total_action_steps=args.total_steps, policy_tracking_weight=args.tracking_weight)
    folder = args.out / "objectives"
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.executors:
        executor = Executor(name)
        objective = folder / f"{executor.value}.xml"
        objective.write_text(objective_xml(executor, settings))
        for delay in args.delays:
            cell = Cell(executor, delay)
            try:
                row = run_cell(args, objective, cell)
            except BenchError as err:
                print(f"bench_success_under_latency: {err}", file=sys.stderr)
                return 2
            print(f"{executor.value} at {delay}: {row['successes']}/{row['episodes']}, {row['unsafe_points']} unsafe points",
                  file=sys.stderr, flush=True)
            rows.append(row)
    title = f"success under latency: policy {policy_label(args.policy)}, {args.world}, seeds {args.seed_start}+, {args.episodes} episodes per cell"
    report(title, rows, COLUMNS, notes=["rate: successes / episodes (an ERROR is not a success); ci95: Wilson score interval; "
                                        "time_to_success_s: median simulated seconds of the successful episodes; "
                                        "unsafe_points: controller ticks outside a joint limit or within the padding of a collision, "
                                        "summed over the cell's episodes; unsafe_episodes: episodes with any"])
    (args.out / "rows.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    if args.plot:
        plot(rows, args.plot, title)
    return 0


if __name__ == "__main__":
    sys.exit(main())
