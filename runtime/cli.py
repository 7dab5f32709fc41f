"""``objective``: run, validate, show and describe BehaviorTree.CPP v4 Objectives.

Exit codes: 0 SUCCESS, 1 FAILURE (the failing node and its reason on stderr), 2 bad input
(the error, ``file:line: Node: what``, on stderr; never a traceback).

The CLI is the composition root: behaviors come from the ``objective.behaviors`` entry points
and worlds from ``objective.worlds``, so the runtime imports neither.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
from pathlib import Path
from typing import Any, Sequence
from xml.sax.saxutils import escape, quoteattr

from .errors import ObjectiveError
from .ports import Direction, PortType
from .registry import Registry

EXIT_SUCCESS, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2

# Nodes BehaviorTree.CPP (and so Groot2) already knows; `objective models` leaves them out.
BTCPP_BUILTINS = frozenset({
    "AlwaysFailure", "AlwaysSuccess", "Delay", "Fallback", "ForceFailure", "ForceSuccess",
    "IfThenElse", "Inverter", "KeepRunningUntilFailure", "Parallel", "ParallelAll", "Precondition",
    "ReactiveFallback", "ReactiveSequence", "Repeat", "RetryUntilSuccessful", "RunOnce", "Script",
    "ScriptCondition", "Sequence", "SequenceWithMemory", "SetBlackboard", "Sleep", "SubTree",
    "Switch2", "Switch3", "Switch4", "Switch5", "Switch6", "Timeout", "UnsetBlackboard",
    "WhileDoElse", "WasEntryUpdated", "SkipUnlessUpdated", "WaitValueUpdate",
})
_MODEL_TYPES = {PortType.STRING: "std::string"}


def _parse_set(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected name=value, got {text!r}")
    return name.strip(), value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="objective",
        description="Run BehaviorTree.CPP v4 Objectives headless.",
        epilog="Exit codes: 0 SUCCESS, 1 FAILURE, 2 bad input.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add_paths(p: argparse.ArgumentParser) -> None:
        p.add_argument("--path", action="append", type=Path, default=[], metavar="DIR",
                       help="another directory of *.xml to find SubTrees in (after objectives/); repeatable")
        p.add_argument("--objectives-dir", type=Path, default=None, metavar="DIR",
                       help="the library searched first for SubTrees (default: the project's objectives/)")

    run = sub.add_parser("run", help="run an Objective until it succeeds or fails")
    run.add_argument("file", type=Path)
    run.add_argument("--tree", metavar="ID", help="the BehaviorTree to run (default: main_tree_to_execute)")
    run.add_argument("--set", action="append", type=_parse_set, default=[], metavar="NAME=VALUE",
                     help="set a root blackboard entry (a string) before the first tick; repeatable")
    run.add_argument("--seed", type=int, default=0, help="seed of the world's layout and random latencies")
    run.add_argument("--realtime", action="store_true", help="pace the ticks to wall-clock time")
    run.add_argument("--ros", action="store_true",
                     help="run on real ROS 2 as node /objective_runtime (implies --realtime); the world's topics, "
                          "controllers and cameras are served on ROS 2 and the policy comes from an adapter "
                          "(--policy none unless given)")
    run.add_argument("--json", action="store_true", help="print a JSON summary as the last line of stdout")
    run.add_argument("--world", metavar="NAME", help="world for trees that need one (default: vla_sim)")
    run.add_argument("--max-seconds", type=_positive_float, metavar="S", help="fail after S seconds of clock time")
    run.add_argument("--policy-latency", metavar="SPEC",
                     help="policy call latency: 'measured' (default), seconds (e.g. 0.3) or lognormal:MEAN,SD")
    run.add_argument("--policy", metavar="SPEC",
                     help="policy the world serves on /get_action_chunk in headless runs: oracle (default), replay:FILE or none")
    run.add_argument("--world-option", action="append", type=_parse_set, default=[], metavar="KEY=VALUE",
                     help="an option of the world, e.g. urdf=robot.urdf for --world robot (repeatable)")
    run.add_argument("--record", type=Path, metavar="DIR",
                     help="record the run into DIR: run.mcap, events.jsonl, plots, camera video, tree.svg, report.html")
    run.add_argument("--tick-hz", type=_positive_float, default=100.0, help=argparse.SUPPRESS)
    add_paths(run)

    val = sub.add_parser("validate", help="load Objectives and report every error (nothing runs)")
    val.add_argument("files", type=Path, nargs="+")
    val.add_argument("--tree", metavar="ID", help="validate only this BehaviorTree (default: every tree in each file)")
    add_paths(val)

    beh = sub.add_parser("behaviors", help="list every registered node with its ports")
    beh.add_argument("--json", action="store_true", help="print JSON instead of text")

    show = sub.add_parser("show", help="print the tree an Objective builds")
    show.add_argument("file", type=Path)
    show.add_argument("--tree", metavar="ID")
    add_paths(show)

    models = sub.add_parser("models", help="print TreeNodesModel XML for Groot2")
    models.add_argument("--all", action="store_true", help="include the nodes BehaviorTree.CPP has built in")
    report = sub.add_parser("report", help="render the plots, video, tree and page of a recording again")
    report.add_argument("dir", type=Path, help="a directory written by `objective run --record DIR`")
    _add_policy_commands(sub)
    _add_demo_commands(sub)
    from evaluation.cli import add_eval_command  # `objective eval` (the evaluation package)

    add_eval_command(sub, _parse_set, _positive_float)
    return parser


def _add_demo_commands(sub: Any) -> None:
    """``record-demos``: oracle demonstrations as a LeRobot dataset (sim.demos, needs `make lerobot`)."""
    demos = sub.add_parser("record-demos", help="record oracle demonstrations in the cell as a local LeRobot dataset")
    demos.add_argument("out", type=Path, help="dataset folder to create")
    demos.add_argument("--episodes", type=int, default=10, help="episodes to record (default 10)")
    demos.add_argument("--seed", type=int, default=0, help="seed of the first episode's layout; episode i uses seed+i")
    demos.add_argument("--world", metavar="NAME", help="world to record in (default: vla_sim if installed, else kinematic)")
    demos.add_argument("--image-size", type=int, default=128, metavar="PX", help="camera frames, square (default 128)")
    demos.add_argument("--steps", type=int, default=250, help="policy steps (0.1 s) recorded per episode (default 250)")
    demos.add_argument("--prompt", default="stack the blue cube on the green cube", help="the task, as the oracle reads it")
    demos.add_argument("--keep-failed", action="store_true", help="keep episodes whose stack check failed")
    demos.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")


def _add_policy_commands(sub: Any) -> None:
    """``serve``, ``adapter``, ``smoke-test``: the policy side (sim.policy, imported lazily)."""
    serve = sub.add_parser("serve", help="run the HTTP inference server (GET /health, POST /infer)")
    serve.add_argument("--backend", required=True, help="oracle, replay or lerobot")
    serve.add_argument("--checkpoint", type=Path, metavar="DIR", help="LeRobot checkpoint folder (--backend lerobot)")
    serve.add_argument("--replay-file", type=Path, metavar="FILE", help="chunks as JSON lines (--backend replay)")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: loopback only)")
    serve.add_argument("--port", type=int, default=0, help="port (default 0: pick a free one, printed at start)")
    serve.add_argument("--insecure-no-key", action="store_true",
                       help="serve /infer without a bearer key when POLICY_SERVER_KEY is unset")
    serve.add_argument("--max-body-bytes", type=int, default=32 * 1024 * 1024, metavar="N",
                       help="refuse larger requests with 413 (default 32 MiB)")
    serve.add_argument("--warmup-joints", metavar="A;B;...", help="joint names of the warmup request (default: the cell's 7)")
    serve.add_argument("--warmup-images", metavar="NAME=HxW;...", default="scene=224x224",
                       help="camera frames of the warmup request (default scene=224x224)")
    serve.add_argument("--warmup-prompt", default="stack the red cube on the blue cube", help="prompt of the warmup request")
    serve.add_argument("--default-guidance", type=int, default=0, metavar="STEPS",
                       help="RTC guidance width used when a request's guidance_horizon is 0")
    serve.add_argument("--tls-cert", type=Path, metavar="FILE", help="serve HTTPS with this certificate (PEM)")
    serve.add_argument("--tls-key", type=Path, metavar="FILE", help="private key of --tls-cert (PEM)")
    serve.add_argument("--tls-client-ca", type=Path, metavar="FILE", help="require client certificates signed by this CA")

    adapter = sub.add_parser("adapter", help="serve GetActionChunk on ROS 2, forwarding to an inference server")
    adapter.add_argument("--infer-url", required=True, metavar="URL",
                         help="the server: http:// on loopback only, or https:// (certificate verified)")
    adapter.add_argument("--service-name", default="/get_action_chunk", help="service to serve (default /get_action_chunk)")
    adapter.add_argument("--timeout", type=_positive_float, default=2.5, metavar="S",
                         help="HTTP deadline per call; keep it below policy_call_timeout (default 2.5)")
    adapter.add_argument("--ca-file", type=Path, metavar="FILE", help="CA bundle to verify an https:// server with")
    adapter.add_argument("--client-cert", type=Path, metavar="FILE", help="client certificate (PEM) for mutual TLS")
    adapter.add_argument("--client-key", type=Path, metavar="FILE", help="private key of --client-cert")
    adapter.add_argument("--log-every", type=int, default=1, metavar="N", help="log the served-chunk count every N chunks")

    smoke = sub.add_parser("smoke-test", help="call a GetActionChunk service once, as ExecutePolicy will, and judge it")
    smoke.add_argument("service", help="the service, e.g. /get_action_chunk")
    smoke.add_argument("--joint-group", required=True, help="SRDF joint group, e.g. manipulator")
    smoke.add_argument("--gripper-joint", help="gripper joint appended last, e.g. robotiq_85_left_knuckle_joint")
    smoke.add_argument("--image-topics", metavar="T1;T2", help="camera topics, ';'-separated")
    smoke.add_argument("--image-names", metavar="N1;N2", help="camera names, index-aligned with --image-topics")
    smoke.add_argument("--prompt", default="", help="task instruction sent with the call")
    smoke.add_argument("--rtc", action="store_true", help="require policy_action_chunk (real-time chunking on)")
    smoke.add_argument("--expected-steps", type=int, metavar="N", help="the chunk must have exactly N steps")
    smoke.add_argument("--timeout", type=_positive_float, default=3.0, metavar="S",
                       help="bound on the call (ExecutePolicy's policy_call_timeout, default 3)")
    smoke.add_argument("--wait", type=_positive_float, default=5.0, metavar="S",
                       help="bound on each wait for the service, joint states and frames (default 5)")
    smoke.add_argument("--joint-states-topic", default="/joint_states")
    smoke.add_argument("--synthetic-images", action="store_true", help="send a gray 224x224 frame per --image-names")
    smoke.add_argument("--synthetic-joints", action="store_true", help="send zeros instead of waiting for joint states")
    smoke.add_argument("--urdf", type=Path, metavar="FILE", help="robot model (with --srdf; default: the simulated cell)")
    smoke.add_argument("--srdf", type=Path, metavar="FILE")


# ------------------------------------------------------------------------------------------------
# Commands
# ------------------------------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace, registry: Registry) -> int:
    from .display import ProgressLine
    from .runner import RunOptions, run_file

    options = RunOptions(
        seed=args.seed,
        realtime=args.realtime or args.ros,
        ros=args.ros,
        tick_hz=args.tick_hz,
        max_seconds=args.max_seconds,
        world=args.world,
        sets=dict(args.set),
        policy_latency=args.policy_latency,
        record_dir=args.record,
        world_options={**dict(args.world_option), **({"policy": args.policy} if args.policy else {})},
    )
    progress = ProgressLine(sys.stderr) if sys.stderr.isatty() else None
    if progress is not None:
        for handler in logging.getLogger("objective").handlers:
            handler.addFilter(lambda record: progress.clear() or True)  # log lines replace the progress line
    interrupts: Any = contextlib.nullcontext()
    if args.ros:
        from .ros.run import graph_description, sigterm_as_interrupt

        options.check()
        logging.getLogger("objective").info("running %s", graph_description(options.ros_node_name))
        interrupts = sigterm_as_interrupt()  # a stopped runner halts the tree and leaves the graph cleanly
    try:
        with interrupts:
            result = run_file(args.file, registry, options, args.tree, args.path, args.objectives_dir, progress)
    finally:
        if progress is not None:
            progress.clear()
    if result.status == "SUCCESS":
        print(f"SUCCESS after {result.sim_seconds:.2f} s ({result.ticks} ticks)", file=sys.stderr)
    else:
        where = f" ({result.failing_location})" if result.failing_location else ""
        node = f"'{result.failing_node}'{where}" if result.failing_node else "the root"
        print(f"FAILURE after {result.sim_seconds:.2f} s: {node} failed: {result.reason or 'no reason given'}",
              file=sys.stderr)
    if args.record is not None:
        print(f"recorded to {args.record}/ (open {args.record / 'report.html'})", file=sys.stderr)
    if args.json:
        print(json.dumps(result.to_json(), default=str))
    return result.exit_code


def cmd_validate(args: argparse.Namespace, registry: Registry) -> int:
    from .loader import validate

    failed = 0
    for file in args.files:
        try:
            trees = validate(file, registry, args.tree, args.path, args.objectives_dir)
        except ObjectiveError as err:
            failed += 1
            print(f"error: {err}", file=sys.stderr)
            continue
        summary = ", ".join(f"{t.tree_id} ({len(t.nodes)} nodes)" for t in trees)
        print(f"ok: {file}: {summary}")
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
                    "default": None if p.required or p.direction is Direction.OUTPUT else p.describe_default(),
                    "required": p.required,
                    "description": p.description,
                }
                for p in spec.cls.ports
            ],
        })
    return out


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
            text = f"      {port['direction']:<6} {port['name']} ({port['type']}, {default})"
            print(text + (f": {port['description']}" if port["description"] else ""))
    return EXIT_SUCCESS


def cmd_show(args: argparse.Namespace, registry: Registry) -> int:
    from .display import tree_text
    from .loader import throwaway_context, load_tree

    tree = load_tree(args.file, registry, throwaway_context(), args.tree, args.path, args.objectives_dir)
    print(tree_text(tree))
    return EXIT_SUCCESS


def models_xml(registry: Registry, include_builtins: bool = False) -> str:
    """TreeNodesModel XML for Groot2: one element per node, ports with type, default and description."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<root BTCPP_format="4">', "  <TreeNodesModel>"]
    for spec in registry.specs():
        if spec.id in BTCPP_BUILTINS and not include_builtins:
            continue
        tag = spec.kind.value
        lines.append(f"    <{tag} ID={quoteattr(spec.id)}>")
        for port in spec.cls.ports:
            attrs = f"name={quoteattr(port.name)} type={quoteattr(_MODEL_TYPES.get(port.type, port.type.value))}"
            if not port.required and port.direction is not Direction.OUTPUT:
                attrs += f" default={quoteattr(port.describe_default())}"
            lines.append(f"      <{port.direction.value} {attrs}>{escape(port.description)}</{port.direction.value}>")
        if spec.cls.description:
            lines.append("      <MetadataFields>")
            lines.append(f"        <Metadata description={quoteattr(spec.cls.description)}/>")
            lines.append("      </MetadataFields>")
        lines.append(f"    </{tag}>")
    lines += ["  </TreeNodesModel>", "</root>"]
    return "\n".join(lines)


def cmd_report(args: argparse.Namespace, registry: Registry) -> int:
    from .report import render_report

    report = render_report(args.dir)
    for name, path in report.files.items():
        print(path)
    for name, error in report.errors.items():
        print(f"error: {name}: {error}", file=sys.stderr)
    return EXIT_FAILURE if report.errors else EXIT_SUCCESS


def cmd_models(args: argparse.Namespace, registry: Registry) -> int:
    print(models_xml(registry, args.all))
    return EXIT_SUCCESS


def _policy_logging() -> None:
    """The policy processes log to stderr (one line per request, served-chunk counts)."""
    _log_to_stderr("sim.policy", "[%(levelname)s] %(name)s: %(message)s")


def cmd_serve(args: argparse.Namespace, registry: Registry) -> int:
    import threading

    from sim.policy.server import (
        BackendOptions, InferenceServer, ServerConfig, WarmupSpec, key_from_env, make_backend,
        parse_warmup_images, serve_forever, stop_on_signals,
    )

    _policy_logging()
    try:
        warmup = WarmupSpec(images=parse_warmup_images(args.warmup_images), prompt=args.warmup_prompt)
        if args.warmup_joints:
            warmup = WarmupSpec(tuple(j.strip() for j in args.warmup_joints.split(";") if j.strip()),
                                warmup.images, warmup.prompt)
        config = ServerConfig(
            host=args.host, port=args.port, key=key_from_env(), insecure_no_key=args.insecure_no_key,
            max_body_bytes=args.max_body_bytes, warmup=warmup,
            tls_cert=args.tls_cert, tls_key=args.tls_key, tls_client_ca=args.tls_client_ca,
        )
        backend = make_backend(args.backend, BackendOptions(args.replay_file, args.default_guidance, args.checkpoint))
        server = InferenceServer(backend, config)
        stop = threading.Event()
        restore = stop_on_signals(stop)
        try:
            serve_forever(server, stop)
        finally:
            restore()
    except (ValueError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return EXIT_SUCCESS


def cmd_adapter(args: argparse.Namespace, registry: Registry) -> int:
    from sim.policy.node import AdapterConfig, run_adapter_node
    from sim.policy.server import key_from_env

    _policy_logging()
    try:
        config = AdapterConfig(
            infer_url=args.infer_url, service_name=args.service_name, timeout=args.timeout, key=key_from_env(),
            ca_file=args.ca_file, client_cert=args.client_cert, client_key=args.client_key, log_every=args.log_every,
        )
        return run_adapter_node(config)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT


def cmd_smoke_test(args: argparse.Namespace, registry: Registry) -> int:
    from sim.policy.smoke import SmokeConfig, run_smoke_test, split_list

    try:
        config = SmokeConfig(
            service_name=args.service, joint_group=args.joint_group, gripper_joint=args.gripper_joint or None,
            image_topics=split_list(args.image_topics), image_names=split_list(args.image_names),
            prompt=args.prompt, rtc=args.rtc, expected_steps=args.expected_steps, timeout=args.timeout,
            wait=args.wait, joint_states_topic=args.joint_states_topic, synthetic_images=args.synthetic_images,
            synthetic_joints=args.synthetic_joints, urdf=args.urdf, srdf=args.srdf,
        )
        report = run_smoke_test(config)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(report.table())
    return EXIT_SUCCESS if report.passed else EXIT_FAILURE


def cmd_record_demos(args: argparse.Namespace, registry: Registry) -> int:
    from sim.demos import DemoOptions, record_demos

    try:
        summary = record_demos(DemoOptions(
            episodes=args.episodes, seed=args.seed, out=args.out, world=args.world, image_size=args.image_size,
            total_steps=args.steps, prompt=args.prompt, keep_failed=args.keep_failed, overwrite=args.overwrite,
        ))
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except RuntimeError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_FAILURE
    dropped = f", dropped seeds {summary.episodes_dropped}" if summary.episodes_dropped else ""
    print(f"{summary.out}: {summary.episodes_kept} episodes, {summary.frames} frames from world '{summary.world}'{dropped}")
    return EXIT_SUCCESS


def cmd_eval(args: argparse.Namespace, registry: Registry) -> int:
    from evaluation.cli import cmd_eval as evaluate

    return evaluate(args, registry)


COMMANDS = {
    "run": cmd_run,
    "validate": cmd_validate,
    "behaviors": cmd_behaviors,
    "show": cmd_show,
    "models": cmd_models,
    "report": cmd_report,
    "serve": cmd_serve,
    "adapter": cmd_adapter,
    "smoke-test": cmd_smoke_test,
    "record-demos": cmd_record_demos,
    "eval": cmd_eval,
}


def main(argv: Sequence[str] | None = None, registry: Registry | None = None) -> int:
    """Entry point of the ``objective`` console script; returns the exit code.

    ``registry`` defaults to every node the installed packages declare (tests pass their own).
    """
    args = build_parser().parse_args(argv)
    _setup_logging()
    try:
        registry = registry if registry is not None else Registry.from_entry_points()
        code = COMMANDS[args.command](args, registry)
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_SUCCESS
    except ObjectiveError as err:
        print(f"error: {err}", file=sys.stderr)
        if getattr(args, "json", False) and args.command in ("run", "eval"):
            print(json.dumps({"status": "ERROR", "reason": str(err)}))
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        _quiet_stdout()
    return code


class _StderrHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """Writes to whatever ``sys.stderr`` is now (tests and wrappers replace it)."""

    @property  # type: ignore[override]
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, value: Any) -> None:
        pass


def _setup_logging() -> None:
    """Runtime messages (LogMessage, warnings) go to stderr, once per process."""
    _log_to_stderr("objective", "[%(levelname)s] %(message)s")


def _log_to_stderr(name: str, fmt: str) -> None:
    logger = logging.getLogger(name)
    if not logger.handlers:
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter(fmt))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False


def _quiet_stdout() -> None:
    """The reader of our stdout went away (``objective behaviors | head``): drop the rest quietly."""
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


if __name__ == "__main__":
    sys.exit(main())
