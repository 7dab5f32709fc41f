"""``objective``: run, validate, show and describe BehaviorTree.CPP v4 Objectives.

Exit codes: 0 SUCCESS (or SKIPPED: the root's children were all skipped), 1 FAILURE (the failing
node and its reason on stderr), 2 bad input or an error while running, such as a failing script or
an unexpected error (the error, ``file:line: Node: what``, on stderr; never a traceback: that goes
to a log file the message names; ``ERROR`` in ``--json``), 130/143 when SIGINT/SIGTERM interrupted
a run. Every piece of Objective-supplied text is printed through ``runtime.app.terminal.printable``.

The CLI is the composition root: behaviors come from the ``objective.behaviors`` entry points,
worlds from ``objective.worlds`` (the default one from ``objective.default_world``) and the
commands beyond the engine's own (``serve``, ``adapter``, ``report``, ``record-demos``, ...) from
``objective.commands`` and the recording of ``--record``/``--live`` from ``objective.run_observers``
(``runtime.app.observer``), so the runtime imports none of them.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import json
import logging
import os
import signal
import sys
from importlib.metadata import PackageNotFoundError, entry_points, version
from pathlib import Path
from typing import Any, Sequence, TextIO

# Runs are headless: MuJoCo (the simulated cell's, when it is installed) renders offscreen unless
# the user chose a GL backend. Its backend is fixed when it is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

from runtime.io.bus import DEFAULT_POLICY_LATENCY
from .command import COMMAND_GROUP, EXIT_BAD_INPUT, EXIT_SUCCESS, OBJECTIVE_FILE_HELP, POLICY_HELP, Command
from runtime.errors import INTERNAL, InternalError, ObjectiveError, error_kind
from runtime.io.interrupt import StopRequest, exit_code_for, signal_name, stop_on_signals
from runtime.tree.ports import FINITE, NUMERIC_TYPES, Direction, PortInfo, PortType
from .protective_stop import DEFAULT_STOP_NAME, PROTECTIVE_STOP, StopInputs
from runtime.tree.registry import Registry
from .terminal import printable

# Nodes BehaviorTree.CPP (and so Groot2) already knows; `objective models` leaves them out.
BTCPP_BUILTINS = frozenset({
    "AlwaysFailure", "AlwaysSuccess", "AsyncFallback", "AsyncSequence", "Delay", "Fallback", "ForceFailure",
    "ForceSuccess", "IfThenElse", "Inverter", "KeepRunningUntilFailure", "LoopBool", "LoopDouble", "LoopInt",
    "LoopString", "Parallel", "ParallelAll", "Precondition", "ReactiveFallback", "ReactiveSequence", "Repeat",
    "RetryUntilSuccessful", "RunOnce", "Script", "ScriptCondition", "Sequence", "SequenceWithMemory",
    "SetBlackboard", "Sleep", "SubTree", "Switch2", "Switch3", "Switch4", "Switch5", "Switch6", "Timeout",
    "TryCatch", "UnsetBlackboard", "WhileDoElse", "WasEntryUpdated", "SkipUnlessUpdated", "WaitValueUpdate",
})
_MODEL_TYPES = {PortType.STRING: "std::string"}


def parse_set(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected name=value, got {text!r}")
    return name.strip(), value


def tcp_port(text: str) -> int:
    if not text.isascii() or not text.isdigit() or int(text) > 65535:
        raise argparse.ArgumentTypeError(f"expected a TCP port number (0-65535), got {text!r}")
    return int(text)


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return value


def add_groot2_arguments(parser: argparse.ArgumentParser) -> None:
    """``--groot2 [PORT]`` and ``--groot2-host``: live monitoring in Groot2 (``runtime.app.groot2``)."""
    parser.add_argument("--groot2", type=tcp_port, nargs="?", const=1667, metavar="PORT",
                        help="serve the running tree to Groot2 (BehaviorTree.CPP's protocol) on PORT and PORT+1 "
                             "(default 1667; 0 = any free pair); needs the monitor extra")
    parser.add_argument("--groot2-host", default="127.0.0.1", metavar="ADDRESS",
                        help="interface Groot2 connects to (default 127.0.0.1; 0.0.0.0 = every interface)")


DISCOVERY_RANGES = ("localhost", "subnet", "system_default", "off")
"""ROS 2's automatic discovery ranges (Jazzy and later), the values of ``--discovery-range``."""


def add_discovery_argument(parser: argparse.ArgumentParser) -> None:
    """``--discovery-range``: who on the network may see the ROS 2 node (``runtime.io.ros.run.set_discovery_range``)."""
    parser.add_argument("--discovery-range", choices=DISCOVERY_RANGES,
                        metavar="RANGE", help="ROS 2 discovery range: localhost (default, unless "
                        "ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise), subnet, system_default or off")


def add_protective_stop_arguments(parser: argparse.ArgumentParser) -> None:
    """``--protective-stop NAME``, ``--deadman-topic`` and ``--deadman-period`` (``runtime.app.protective_stop``)."""
    parser.add_argument("--protective-stop", default=DEFAULT_STOP_NAME, metavar="NAME",
                        help="the std_msgs/Bool topic and std_srvs/Trigger service that stop a run (FAILURE); '' for none")
    parser.add_argument("--deadman-topic", default="", metavar="TOPIC",
                        help="a std_msgs/Bool heartbeat (true) that must keep arriving while a policy runs")
    parser.add_argument("--deadman-period", type=positive_float, default=0.5, metavar="S",
                        help="seconds the deadman heartbeat may be silent (default 0.5)")


def protective_stop_inputs(args: argparse.Namespace) -> StopInputs:
    """The ``StopInputs`` of ``add_protective_stop_arguments``' options (a ``--protective-stop``
    left None, to tell whether it was given: the default name)."""
    name = DEFAULT_STOP_NAME if args.protective_stop is None else args.protective_stop
    return StopInputs(name, name, args.deadman_topic, args.deadman_period)


def groot2_server(args: argparse.Namespace) -> Any:
    """The Groot2 server ``--groot2`` asks for (a context manager), or a null context."""
    if args.groot2 is None:
        return contextlib.nullcontext()
    from .groot2 import Groot2Options, Groot2Server

    server = Groot2Server(Groot2Options(port=args.groot2, host=args.groot2_host))
    logging.getLogger("objective").info("Groot2: connect to %s (port %d)", server.host, server.port)
    return server


def installed_version() -> str:
    """The installed objective-runtime's version (``pyproject.toml``), or a note that it is not installed."""
    try:
        return version("objective-runtime")
    except PackageNotFoundError:
        return "(objective-runtime is not installed: pip install -e .)"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The CLI's parser. Installed commands (``objective.commands``) are loaded unless ``command``
    is one of the engine's own: ``objective run`` imports no plug-in command's module."""
    parser = argparse.ArgumentParser(
        prog="objective",
        description="Run BehaviorTree.CPP v4 Objectives headless.",
        epilog="Exit codes: 0 SUCCESS (or SKIPPED), 1 FAILURE, 2 bad input or a run-time error (ERROR), "
               "130/143 interrupted (SIGINT/SIGTERM).",
    )
    parser.add_argument("--version", action="version", version=f"objective {installed_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add_paths(p: argparse.ArgumentParser) -> None:
        p.add_argument("--path", action="append", type=Path, default=[], metavar="DIR",
                       help="another directory of *.xml to find SubTrees in (after objectives/); repeatable")
        p.add_argument("--objectives-dir", type=Path, default=None, metavar="DIR",
                       help="the library searched first for SubTrees (default: the project's objectives/)")

    run = sub.add_parser("run", help="run an Objective until it succeeds or fails")
    run.add_argument("file", type=Path, help=OBJECTIVE_FILE_HELP)
    run.add_argument("--tree", metavar="ID", help="the BehaviorTree to run (default: main_tree_to_execute)")
    run.add_argument("--set", action="append", type=parse_set, default=[], metavar="NAME=VALUE",
                     help="set a root blackboard entry (a string) before the first tick; repeatable")
    run.add_argument("--seed", type=int, default=0, help="seed of the world's layout and random latencies")
    run.add_argument("--realtime", action="store_true", help="pace the ticks to wall-clock time")
    run.add_argument("--ros", action="store_true",
                     help="run on real ROS 2 as node /objective_runtime (implies --realtime); the world's topics, "
                          "controllers and cameras are served on ROS 2 and the policy comes from an adapter "
                          "(--policy none unless given)")
    run.add_argument("--use-sim-time", action="store_true",
                     help="with --ros: take the clock from the graph's /clock (a simulated robot's, objective sim-robot)")
    run.add_argument("--realtime-priority", type=int, metavar="N",
                     help="with --realtime or --ros: tick at SCHED_FIFO priority N (1-99), ahead of ordinary processes, "
                          "as ros2_control's update loop does (needs root or an rtprio limit; else a warning)")
    run.add_argument("--json", action="store_true", help="print a JSON summary as the last line of stdout")
    run.add_argument("--world", metavar="NAME", help="world for trees that need one (default: the installation's, vla_sim here)")
    run.add_argument("--max-seconds", type=positive_float, metavar="S", help="fail after S seconds of clock time")
    add_protective_stop_arguments(run)
    run.add_argument("--policy-latency", metavar="SPEC",
                     help=f"policy call latency: seconds ({DEFAULT_POLICY_LATENCY} by default, as objective eval), "
                          "'measured' (the policy's own wall time), lognormal:MEAN,SD or "
                          "trace:FILE (one latency per line, per call, the last repeating)")
    run.add_argument("--policy", metavar="SPEC", help=POLICY_HELP)
    run.add_argument("--world-option", action="append", type=parse_set, default=[], metavar="KEY=VALUE",
                     help="an option of the world, e.g. urdf=robot.urdf for --world robot (repeatable)")
    run.add_argument("--record", type=Path, metavar="DIR",
                     help="record the run into DIR: run.mcap, events.jsonl, plots, camera video, tree.svg, report.html")
    run.add_argument("--live", type=tcp_port, nargs="?", const=8765, metavar="PORT",
                     help="serve the run's topics to Foxglove on ws://127.0.0.1:PORT while it runs (default 8765; 0 = any free port)")
    add_discovery_argument(run)
    add_groot2_arguments(run)
    run.add_argument("--tick-hz", type=positive_float, default=100.0, help=argparse.SUPPRESS)
    add_paths(run)

    val = sub.add_parser("validate", help="load Objectives and report every error (nothing runs)")
    val.add_argument("files", type=Path, nargs="+", help="the Objectives: BehaviorTree.CPP v4 XML files")
    val.add_argument("--tree", metavar="ID", help="validate only this BehaviorTree (default: every tree in each file)")
    val.add_argument("--world", metavar="NAME",
                     help="also check what the world knows: frames, objects, joint groups and joints, waypoints, "
                          "services and actions and their types (the world is started; nothing moves)")
    val.add_argument("--world-option", action="append", type=parse_set, default=[], metavar="KEY=VALUE",
                     help="an option of the world, as for `objective run` (repeatable)")
    add_paths(val)

    beh = sub.add_parser("behaviors", help="list every registered node with its ports")
    beh.add_argument("--json", action="store_true", help="print JSON instead of text")

    show = sub.add_parser("show", help="print the tree an Objective builds")
    show.add_argument("file", type=Path, help=OBJECTIVE_FILE_HELP)
    show.add_argument("--tree", metavar="ID")
    add_paths(show)

    models = sub.add_parser("models", help="print TreeNodesModel XML for Groot2")
    models.add_argument("--all", action="store_true", help="include the nodes BehaviorTree.CPP has built in")
    if command not in sub.choices:
        _add_plugin_commands(sub)
    return parser


# ------------------------------------------------------------------------------------------------
# Commands
# ------------------------------------------------------------------------------------------------
def _add_plugin_commands(sub: Any) -> None:
    """The commands installed packages declare in ``objective.commands``, in name order.

    A command that fails to load, or takes a name already in use, is left out with a warning on
    stderr: the engine's own commands keep working."""
    for ep in sorted(entry_points(group=COMMAND_GROUP), key=lambda e: e.name):
        try:
            command = ep.load()
        except Exception as err:  # a broken plug-in must not take the whole CLI down
            print(f"warning: command '{ep.name}' ({ep.value}) failed to load: {type(err).__name__}: {err}",
                  file=sys.stderr)
            continue
        if not isinstance(command, Command):
            print(f"warning: command '{ep.name}' ({ep.value}) is not a runtime.app.command.Command", file=sys.stderr)
            continue
        if ep.name in sub.choices:
            print(f"warning: command '{ep.name}' ({ep.value}) is defined twice; keeping the first", file=sys.stderr)
            continue
        parser = sub.add_parser(ep.name, help=command.help)
        command.add_arguments(parser)
        parser.set_defaults(plugin_command=command)


def cmd_run(args: argparse.Namespace, registry: Registry, stop: StopRequest | None = None) -> int:
    """``objective run``; ``stop`` is where ``main``'s SIGINT/SIGTERM handlers ask the run to stop."""
    from .display import ProgressLine
    from .observer import RunObserver
    from .runner import RunOptions, run_file

    options = RunOptions(
        seed=args.seed,
        realtime=args.realtime or args.ros,
        ros=args.ros,
        use_sim_time=args.use_sim_time,
        tick_hz=args.tick_hz,
        realtime_priority=args.realtime_priority,
        max_seconds=args.max_seconds,
        world=args.world,
        sets=dict(args.set),
        policy_latency=args.policy_latency or (None if args.ros else DEFAULT_POLICY_LATENCY),
        record_dir=args.record,
        live_port=args.live,
        world_options={**dict(args.world_option), **({"policy": args.policy} if args.policy else {})},
        protective_stop=protective_stop_inputs(args),
    )
    progress = ProgressLine(sys.stderr) if sys.stderr.isatty() else None
    if progress is not None:
        def clear_progress(record: logging.LogRecord) -> bool:  # log lines replace the progress line
            progress.clear()
            return True

        for handler in logging.getLogger("objective").handlers:
            handler.addFilter(clear_progress)
    if args.discovery_range is not None and not args.ros:
        raise ObjectiveError("--discovery-range sets who may discover the run's ROS 2 node: it needs --ros")
    if args.ros:
        from runtime.io.ros.run import graph_description, set_discovery_range

        set_discovery_range(args.discovery_range)
        options.check()
        logging.getLogger("objective").info("running %s", graph_description(options.ros_node_name))
    try:
        with groot2_server(args) as groot2:
            observers: list[RunObserver] = [] if progress is None else [progress]
            if groot2 is not None:
                observers.append(groot2.observer())
            result = run_file(args.file, registry, options, args.tree, args.path, args.objectives_dir, observers, stop)
    finally:
        if progress is not None:
            progress.clear()
    print(run_outcome_line(result), file=sys.stderr)
    if args.record is not None:
        print(f"recorded to {args.record}/ (open {args.record / 'report.html'})", file=sys.stderr)
        if result.extra.get("recording_incomplete"):
            print(f"partial recording: {printable(result.extra['recording_incomplete'])}", file=sys.stderr)
    if args.json:
        print(json.dumps(result.to_json(), default=str))
    return result.exit_code


def run_outcome_line(result: Any) -> str:
    """The line ``objective run`` ends with on stderr: how the run ended, and where."""
    if result.status == "SUCCESS":
        return f"SUCCESS after {result.sim_seconds:.2f} s ({result.ticks} ticks)"
    if result.status == "SKIPPED":
        return f"SKIPPED after {result.sim_seconds:.2f} s: every child of the root was skipped, nothing ran"
    if result.status == "INTERRUPTED":
        return f"INTERRUPTED after {result.sim_seconds:.2f} s ({result.ticks} ticks): {printable(result.reason)}"
    if result.status == "ERROR":
        return f"{error_label(result.failure_kind)}: {printable(result.reason)}"
    if result.failure_kind == PROTECTIVE_STOP:  # no node failed: the run was stopped from outside
        return f"FAILURE after {result.sim_seconds:.2f} s ({result.ticks} ticks): {printable(result.reason)}"
    where = f" ({printable(result.failing_location)})" if result.failing_location else ""
    node = f"'{printable(result.failing_node)}'{where}" if result.failing_node else "the root"
    return (f"FAILURE after {result.sim_seconds:.2f} s: {node} failed: "
            f"{printable(result.reason) or 'no reason given'}")


def error_label(failure_kind: str | None) -> str:
    """``internal error`` for a bug (its message names the crash report), else ``error``."""
    return "internal error" if failure_kind == INTERNAL else "error"


def cmd_validate(args: argparse.Namespace, registry: Registry) -> int:
    """Every error of every file, each on its own line; with ``--world``, what the world does not have too."""
    from runtime.tree.loader import throwaway_context, validate

    with contextlib.ExitStack() as stack:
        context, check = throwaway_context, None
        if args.world is not None:
            from .world_check import started_world

            started = stack.enter_context(started_world(args.world, dict(args.world_option)))
            context, check = (lambda: started.context), started.check
        failed = 0
        for file in args.files:
            try:
                found = validate(file, registry, args.tree, args.path, args.objectives_dir, context, check)
            except ObjectiveError as err:
                failed += 1
                print(f"error: {printable(err)}", file=sys.stderr)
                continue
            for problem in found.errors:
                print(f"error: {printable(problem)}", file=sys.stderr)
            if found.errors:
                failed += 1
                continue
            summary = ", ".join(f"{t.tree_id} ({len(t.nodes)} nodes)" for t in found.trees)
            print(printable(f"ok: {file}: {summary}"))
    return EXIT_BAD_INPUT if failed else EXIT_SUCCESS


def behaviors_data(registry: Registry) -> list[dict[str, Any]]:
    """Every registered node with its ports: what `objective behaviors --json` prints."""
    out = []
    for spec in registry.specs():
        out.append({
            "id": spec.id,
            "kind": spec.kind.value,
            "description": spec.cls.description,
            "ports": [
                {
                    "name": p.name,
                    "direction": p.direction.value.removesuffix("_port"),
                    "type": p.type.value,
                    "default": p.describe_default() if p.has_default else None,
                    "required": p.required,
                    "description": p.description,
                    "valid": port_range(p),
                }
                for p in spec.cls.ports
            ],
        })
    return out


def port_range(port: PortInfo) -> str | None:
    """The values a numeric input port accepts, as ``objective behaviors`` and ``models`` show them."""
    if port.type not in NUMERIC_TYPES or port.direction is Direction.OUTPUT:
        return None
    valid = str(port.valid or FINITE)
    return valid + (" each" if port.type in (PortType.FLOAT_LIST, PortType.INT_LIST) else "")


def cmd_behaviors(args: argparse.Namespace, registry: Registry) -> int:
    data = behaviors_data(registry)
    if args.json:
        print(json.dumps(data, indent=2))
        return EXIT_SUCCESS
    for node in data:
        print(f"{node['id']}  [{node['kind']}]")
        if node["description"]:
            print(f"    {node['description']}")
        for port in node["ports"]:
            if port["required"]:
                default = "required"
            elif port["default"] is None:
                default = "optional"
            else:
                default = f"default {port['default']!r}"
            valid = f", valid {port['valid']}" if port["valid"] else ""
            text = f"      {port['direction']:<6} {port['name']} ({port['type']}, {default}{valid})"
            print(text + (f": {port['description']}" if port["description"] else ""))
    return EXIT_SUCCESS


def cmd_show(args: argparse.Namespace, registry: Registry) -> int:
    from .display import tree_text
    from runtime.tree.loader import throwaway_context, load_tree

    tree = load_tree(args.file, registry, throwaway_context(), args.tree, args.path, args.objectives_dir)
    print("\n".join(printable(line) for line in tree_text(tree).split("\n")))  # not splitlines(): it splits at U+2028 too
    return EXIT_SUCCESS


def models_xml(registry: Registry, include_builtins: bool = False) -> str:
    """TreeNodesModel XML for Groot2: one element per node, ports with type, default and description."""
    from xml.sax.saxutils import escape, quoteattr  # imports urllib.request, http.client, ssl: not for a run

    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<root BTCPP_format="4">', "  <TreeNodesModel>"]
    for spec in registry.specs():
        if spec.id in BTCPP_BUILTINS and not include_builtins:
            continue
        tag = spec.kind.value
        lines.append(f"    <{tag} ID={quoteattr(spec.id)}>")
        for port in spec.cls.ports:
            attrs = f"name={quoteattr(port.name)} type={quoteattr(_MODEL_TYPES.get(port.type, port.type.value))}"
            if port.has_default:
                attrs += f" default={quoteattr(port.describe_default())}"
            valid = port_range(port)
            text = f"{port.description} (valid: {valid})" if valid else port.description
            lines.append(f"      <{port.direction.value} {attrs}>{escape(text)}</{port.direction.value}>")
        if spec.cls.description:
            lines.append("      <MetadataFields>")
            lines.append(f"        <Metadata description={quoteattr(spec.cls.description)}/>")
            lines.append("      </MetadataFields>")
        lines.append(f"    </{tag}>")
    lines += ["  </TreeNodesModel>", "</root>"]
    return "\n".join(lines)


def cmd_models(args: argparse.Namespace, registry: Registry) -> int:
    print(models_xml(registry, args.all))
    return EXIT_SUCCESS


COMMANDS = {
    "run": cmd_run,
    "validate": cmd_validate,
    "behaviors": cmd_behaviors,
    "show": cmd_show,
    "models": cmd_models,
}


def _installed_registry() -> Registry:
    """Every node the installed packages declare. Importing their modules makes ~70,000 objects;
    the cyclic collector would walk them again and again while they load (~0.1 s of a start),
    so it is paused meanwhile and what they made is then frozen (``gc.freeze``: kept out of every
    later collection; module-level objects live as long as the process anyway)."""
    if not gc.isenabled():
        return Registry.from_entry_points()
    gc.disable()
    try:
        return Registry.from_entry_points()
    finally:
        gc.freeze()
        gc.enable()


def main(argv: Sequence[str] | None = None, registry: Registry | None = None) -> int:
    """Entry point of the ``objective`` console script; returns the exit code.

    ``registry`` defaults to every node the installed packages declare (tests pass their own).
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(argv[0] if argv else None).parse_args(argv)
    _setup_logging()
    stop = StopRequest()
    # For `run`, SIGINT and SIGTERM stop the run at the next tick (halted, recorded, summarised),
    # from now on: a signal while the behaviors load still gets the INTERRUPTED summary.
    signals = stop_on_signals(stop) if args.command == "run" else contextlib.nullcontext()
    try:
        with signals:
            plugin = getattr(args, "plugin_command", None)
            code: int
            if registry is None and (plugin is None or plugin.needs_registry):
                registry = _installed_registry()
            if plugin is not None:
                code = plugin.run(args, registry)
            elif args.command == "run":
                assert registry is not None  # found above: no plug-in command
                code = cmd_run(args, registry, stop)
            else:
                assert registry is not None  # found above: no plug-in command
                code = COMMANDS[args.command](args, registry)
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_SUCCESS
    except (ObjectiveError, InternalError) as err:
        return _error_exit(args, str(err), error_kind(err))
    except KeyboardInterrupt as err:  # a second signal, or one outside a run
        name = signal_name(getattr(err, "signum", signal.SIGINT))
        print(f"interrupted ({name})", file=sys.stderr)
        if getattr(args, "json", False) and args.command == "run":
            print(json.dumps({"status": "INTERRUPTED", "reason": f"{name} before the run could stop"}))
        return exit_code_for(getattr(err, "signum", signal.SIGINT))
    except Exception as err:  # a bug: one paragraph here, the traceback in a file
        from runtime.tree.crash import describe_crash, write_traceback

        stopped = f"`objective {args.command}` stopped"
        return _error_exit(args, str(describe_crash(err, None, write_traceback(err, None), consequence=stopped)), INTERNAL)
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        _quiet_stdout()
    return code


def _error_exit(args: argparse.Namespace, message: str, failure_kind: str) -> int:
    print(f"{error_label(failure_kind)}: {printable(message)}", file=sys.stderr)
    if getattr(args, "json", False) and args.command in ("run", "eval"):
        print(json.dumps({"status": "ERROR", "reason": message, "failure_kind": failure_kind}))
    return EXIT_BAD_INPUT


class _StderrHandler(logging.StreamHandler[TextIO]):
    """Writes to whatever ``sys.stderr`` is now (tests and wrappers replace it), made printable."""

    def format(self, record: logging.LogRecord) -> str:
        return printable(super().format(record))

    @property
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, value: Any) -> None:
        pass


def _setup_logging() -> None:
    """Runtime messages (LogMessage, warnings) go to stderr, once per process; so do the warnings
    of every other logger (a policy adapter's), made printable like them."""
    log_to_stderr("objective", "[%(levelname)s] %(message)s")
    log_to_stderr("", "[%(levelname)s] %(name)s: %(message)s", logging.WARNING)


def log_to_stderr(name: str, fmt: str, level: int = logging.INFO) -> None:
    """Send the logger ``name`` (and its children; "" is the root) to stderr at ``level`` and
    above, made printable, once per process."""
    logger = logging.getLogger(name)
    if not any(isinstance(handler, _StderrHandler) for handler in logger.handlers):
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter(fmt))
        logger.addHandler(handler)
        logger.setLevel(level)
        logger.propagate = False


def _quiet_stdout() -> None:
    """The reader of our stdout went away (``objective behaviors | head``): drop the rest quietly."""
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


if __name__ == "__main__":
    sys.exit(main())
