"""``objective server``: the Objective server's command (``runtime.ros.objective_server``).

Registered in the ``objective.commands`` entry-point group; rclpy and the server's interfaces
are imported only when it runs, so ``objective --help`` loads nothing heavy.
"""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from runtime.cli import add_groot2_arguments, add_protective_stop_arguments, groot2_server, parse_set, positive_float, protective_stop_inputs
from runtime.command import EXIT_SUCCESS, Command
from runtime.interrupt import StopRequest, stop_on_signals
from runtime.registry import Registry


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", type=Path, help="the library: every *.xml under it is an Objective, named by its main tree")
    parser.add_argument("--path", action="append", type=Path, default=[], metavar="DIR",
                        help="another directory of *.xml to find SubTrees in (after DIR); repeatable")
    parser.add_argument("--world", metavar="NAME", help="world for Objectives that need one (default: the installation's)")
    parser.add_argument("--world-option", action="append", type=parse_set, default=[], metavar="KEY=VALUE",
                        help="an option of the world (repeatable)")
    parser.add_argument("--policy", metavar="SPEC", help="policy the world serves in headless runs: oracle, replay:FILE or none")
    parser.add_argument("--seed", type=int, default=0, help="seed of every run's world")
    parser.add_argument("--realtime", action="store_true", help="pace the runs to wall-clock time")
    parser.add_argument("--ros", action="store_true",
                        help="run each Objective on real ROS 2 as node /objective_runtime (implies --realtime), "
                             "as `objective run --ros`")
    parser.add_argument("--max-seconds", type=positive_float, metavar="S", help="fail a run after S seconds of clock time")
    add_groot2_arguments(parser)
    add_protective_stop_arguments(parser)


def _serve(args: argparse.Namespace, registry: Registry) -> int:
    from runtime.ros.objective_server import NODE_NAME, ObjectiveServer, ServerOptions
    from runtime.ros.run import graph_description
    from runtime.runner import RunOptions

    options = RunOptions(
        seed=args.seed, realtime=args.realtime or args.ros, ros=args.ros, max_seconds=args.max_seconds,
        world=args.world,
        world_options={**dict(args.world_option), **({"policy": args.policy} if args.policy else {})},
        protective_stop=protective_stop_inputs(args),
    )
    log = logging.getLogger("objective")
    stop = StopRequest()
    with groot2_server(args) as groot2, stop_on_signals(stop):
        server = ObjectiveServer(ServerOptions(args.dir, options, list(args.path), groot2), registry)
        try:
            count = len(server.library.objectives())
            log.info("serving %d Objectives of %s %s; SIGINT or SIGTERM stops", count, args.dir,
                     graph_description(NODE_NAME))
            while not stop.requested:
                time.sleep(0.1)
            log.info("stopping (%s)", "a run was halted" if server.cancel("the Objective server is stopping")
                     else "nothing was running")
        finally:
            server.close()
    return EXIT_SUCCESS


SERVER = Command("serve a library of Objectives on ROS 2: /do_objective, /cancel_objective, /list_objectives",
                 _arguments, _serve)
