"""``objective server`` (``runtime.app.server.objective_server``) and ``objective client`` (``runtime.app.server.client``).

Registered in the ``objective.commands`` entry-point group; rclpy and the server's interfaces
are imported only when it runs, so ``objective --help`` loads nothing heavy.
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from typing import Any

from runtime.app.cli import (
    add_discovery_argument,
    add_groot2_arguments,
    add_protective_stop_arguments,
    groot2_server,
    parse_set,
    positive_float,
    protective_stop_inputs,
)
from runtime.app.command import EXIT_SUCCESS, POLICY_HELP, Command
from runtime.io.interrupt import StopRequest, stop_on_signals
from runtime.tree.registry import Registry


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", type=Path, help="the library: every *.xml under it is an Objective, named by its main tree")
    parser.add_argument("--path", action="append", type=Path, default=[], metavar="DIR",
                        help="another directory of *.xml to find SubTrees in (after DIR, before the shipped objectives/); repeatable")
    parser.add_argument("--world", metavar="NAME", help="world for Objectives that need one (default: the installation's)")
    parser.add_argument("--world-option", action="append", type=parse_set, default=[], metavar="KEY=VALUE",
                        help="an option of the world (repeatable)")
    parser.add_argument("--policy", metavar="SPEC", help=POLICY_HELP)
    parser.add_argument("--seed", type=int, default=0, help="seed of every run's world")
    parser.add_argument("--realtime", action="store_true", help="pace the runs to wall-clock time")
    parser.add_argument("--ros", action="store_true",
                        help="run each Objective on real ROS 2 as node /objective_runtime (implies --realtime), "
                             "as `objective run --ros`")
    parser.add_argument("--max-seconds", type=positive_float, metavar="S", help="fail a run after S seconds of clock time")
    add_discovery_argument(parser)
    add_groot2_arguments(parser)
    add_protective_stop_arguments(parser)


def _serve(args: argparse.Namespace, registry: Registry) -> int:
    from runtime.app.server.objective_server import NODE_NAME, SHUTDOWN, ObjectiveServer, ServerOptions
    from runtime.io.ros.run import graph_description, set_discovery_range
    from runtime.app.runner import RunOptions

    set_discovery_range(args.discovery_range)

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
            log.info("stopping (%s)", "a run was halted" if server.cancel(SHUTDOWN)
                     else "nothing was running")
        finally:
            server.close()
    return EXIT_SUCCESS


SERVER = Command("serve a library of Objectives on ROS 2: /do_objective, /cancel_objective, /list_objectives",
                 _arguments, _serve)


def _override(text: str) -> Any:
    from runtime.app.objective_library import parse_override

    try:
        return parse_override(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _client_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--wait", type=positive_float, default=10.0, metavar="S",
                        help="how long to wait for the server to answer (default 10 s)")
    actions = parser.add_subparsers(dest="client_action", required=True, metavar="ACTION",
                                    help="list, start NAME or cancel (objective client ACTION --help)")
    actions.add_parser("list", help="the server's Objectives with their ports and load errors, and what runs")
    start = actions.add_parser("start", help="run an Objective by name, printing its running nodes, until it ends "
                                             "(SIGINT cancels it); exits as `objective run` does")
    start.add_argument("name", help="the Objective's name, as `objective client list` gives it")
    start.add_argument("--override", action="append", type=_override, default=[], metavar="PORT=VALUE",
                       help="set a port the Objective declares (its TreeNodesModel entry), as MoveIt Pro's port "
                            "overrides do; a node's port inside it is out of reach (repeatable)")
    start.add_argument("--set", action="append", type=parse_set, default=[], metavar="NAME=VALUE",
                       help="set a root blackboard entry before the first tick, as `objective run --set` (repeatable)")
    start.add_argument("--json", action="store_true", help="print the run's JSON summary as the last line of stdout")
    actions.add_parser("cancel", help="cancel the Objective the server is running, whoever started it")


def _client(args: argparse.Namespace, registry: Registry) -> int:
    import sys

    from runtime.app.cli import run_outcome_line
    from runtime.app.command import EXIT_FAILURE
    from runtime.app.server.client import ObjectiveClient, feedback_line, list_lines
    from runtime.app.terminal import printable

    client = ObjectiveClient(wait_s=args.wait)
    try:
        if args.client_action == "list":
            for line in list_lines(client.list()):
                print(printable(line))
            return EXIT_SUCCESS
        if args.client_action == "cancel":
            answer = client.cancel()
            print(printable(answer.message), file=sys.stderr)
            return EXIT_SUCCESS if answer.success else EXIT_FAILURE
        shown: list[tuple[str, ...]] = []

        def show(feedback: Any) -> None:
            running = tuple(feedback.running_nodes)
            if not shown or shown[-1] != running:
                shown.append(running)
                print(printable(feedback_line(feedback)), file=sys.stderr)

        stop = StopRequest()
        with stop_on_signals(stop):
            outcome = client.start(args.name, list(args.override), dict(args.set), show, stop)
        print(run_outcome_line(outcome.result), file=sys.stderr)
        if args.json:
            print(json.dumps(outcome.result.to_json(), default=str))
        return outcome.result.exit_code
    finally:
        client.close()


CLIENT = Command("drive an Objective server without ros2: list, start NAME (with overrides, feedback), cancel",
                 _client_arguments, _client)
