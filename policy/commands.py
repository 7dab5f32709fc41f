"""The policy side's commands: ``serve``, ``adapter`` and ``smoke-test``.

Registered in the ``objective.commands`` entry-point group (see ``runtime.app.command.Command``); each
imports its module only when it runs, so ``objective --help`` loads nothing heavy.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from runtime.app.cli import log_to_stderr, positive_float, tcp_port
from runtime.app.command import EXIT_BAD_INPUT, EXIT_FAILURE, EXIT_SUCCESS, Command
from runtime.errors import ObjectiveError
from runtime.tree.registry import Registry


def _policy_logging() -> None:
    """The policy processes log to stderr (one line per request, served-chunk counts)."""
    log_to_stderr("policy", "[%(levelname)s] %(name)s: %(message)s")


def _serve_arguments(serve: argparse.ArgumentParser) -> None:
    serve.add_argument("--backend", required=True,
                       help="a name in the objective.policy_backends group (oracle, replay or lerobot here), "
                            "or your own factory: FILE.py:NAME or MODULE:NAME, called as NAME(BackendOptions)")
    serve.add_argument("--checkpoint", type=Path, metavar="DIR", help="LeRobot checkpoint folder (--backend lerobot)")
    serve.add_argument("--replay-file", type=Path, metavar="FILE", help="chunks as JSON lines (--backend replay)")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: loopback only)")
    serve.add_argument("--port", type=tcp_port, default=0, help="port (default 0: pick a free one, printed at start)")
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
    serve.add_argument("--noise-scale", type=float, metavar="SCALE",
                       help="scale of a denoising policy's starting noise: 1 samples as trained, 0 answers one chunk "
                            "per observation (default: the checkpoint's objective_policy.json, else 1)")
    serve.add_argument("--tls-cert", type=Path, metavar="FILE", help="serve HTTPS with this certificate (PEM)")
    serve.add_argument("--tls-key", type=Path, metavar="FILE", help="private key of --tls-cert (PEM)")
    serve.add_argument("--tls-client-ca", type=Path, metavar="FILE", help="require client certificates signed by this CA")


def _serve(args: argparse.Namespace, registry: Registry) -> int:
    import threading

    from .server import (
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
        backend = make_backend(args.backend, BackendOptions(args.replay_file, args.default_guidance, args.checkpoint,
                                                             args.noise_scale))
        server = InferenceServer(backend, config)
        stop = threading.Event()
        restore = stop_on_signals(stop)
        try:
            serve_forever(server, stop)
        finally:
            restore()
    except (ObjectiveError, OSError) as err:  # a bug is no bad input: it reaches the CLI's crash report
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return EXIT_SUCCESS


def _adapter_arguments(adapter: argparse.ArgumentParser) -> None:
    adapter.add_argument("--infer-url", required=True, metavar="URL",
                         help="the server: http:// on loopback only, or https:// (certificate verified)")
    adapter.add_argument("--service-name", default="/get_action_chunk", help="service to serve (default /get_action_chunk)")
    adapter.add_argument("--timeout", type=positive_float, default=2.5, metavar="S",
                         help="HTTP deadline per call; keep it below policy_call_timeout (default 2.5)")
    adapter.add_argument("--ca-file", type=Path, metavar="FILE", help="CA bundle to verify an https:// server with")
    adapter.add_argument("--client-cert", type=Path, metavar="FILE", help="client certificate (PEM) for mutual TLS")
    adapter.add_argument("--client-key", type=Path, metavar="FILE", help="private key of --client-cert")
    adapter.add_argument("--log-every", type=int, default=1, metavar="N", help="log the served-chunk count every N chunks")


def _adapter(args: argparse.Namespace, registry: Registry) -> int:
    from .node import AdapterConfig, run_adapter_node
    from .server import key_from_env

    _policy_logging()
    try:
        config = AdapterConfig(
            infer_url=args.infer_url, service_name=args.service_name, timeout=args.timeout, key=key_from_env(),
            ca_file=args.ca_file, client_cert=args.client_cert, client_key=args.client_key, log_every=args.log_every,
        )
        return run_adapter_node(config)
    except ObjectiveError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT


def _smoke_arguments(smoke: argparse.ArgumentParser) -> None:
    smoke.add_argument("service", help="the service, e.g. /get_action_chunk")
    smoke.add_argument("--joints", metavar="A;B;...", help="the joints the policy commands, base to tip, ';'-separated")
    smoke.add_argument("--joint-group", help="or: the SRDF group of --urdf/--srdf, e.g. manipulator")
    smoke.add_argument("--urdf", type=Path, metavar="FILE", help="the robot description --joint-group is read from")
    smoke.add_argument("--srdf", type=Path, metavar="FILE", help="its semantic description (with --urdf)")
    smoke.add_argument("--gripper-joint", help="gripper joint appended last, e.g. robotiq_85_left_knuckle_joint")
    smoke.add_argument("--image-topics", metavar="T1;T2", help="camera topics, ';'-separated")
    smoke.add_argument("--image-names", metavar="N1;N2", help="camera names, index-aligned with --image-topics")
    smoke.add_argument("--prompt", default="", help="task instruction sent with the call")
    smoke.add_argument("--rtc", action="store_true", help="require policy_action_chunk (real-time chunking on)")
    smoke.add_argument("--expected-steps", type=int, metavar="N", help="the chunk must have exactly N steps")
    smoke.add_argument("--timeout", type=positive_float, default=3.0, metavar="S",
                       help="bound on the call (ExecutePolicy's policy_call_timeout, default 3)")
    smoke.add_argument("--wait", type=positive_float, default=5.0, metavar="S",
                       help="bound on each wait for the service, joint states and frames (default 5)")
    smoke.add_argument("--joint-states-topic", default="/joint_states")
    smoke.add_argument("--synthetic-images", action="store_true", help="send a gray 224x224 frame per --image-names")
    smoke.add_argument("--synthetic-joints", action="store_true", help="send zeros instead of waiting for joint states")


def _smoke_test(args: argparse.Namespace, registry: Registry) -> int:
    from .smoke import SmokeConfig, run_smoke_test, split_list

    try:
        config = SmokeConfig(
            service_name=args.service, joint_group=args.joint_group, joints=split_list(args.joints),
            gripper_joint=args.gripper_joint or None,
            image_topics=split_list(args.image_topics), image_names=split_list(args.image_names),
            prompt=args.prompt, rtc=args.rtc, expected_steps=args.expected_steps, timeout=args.timeout,
            wait=args.wait, joint_states_topic=args.joint_states_topic, synthetic_images=args.synthetic_images,
            synthetic_joints=args.synthetic_joints, urdf=args.urdf, srdf=args.srdf,
        )
        report = run_smoke_test(config)
    except ObjectiveError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(report.table())
    return EXIT_SUCCESS if report.passed else EXIT_FAILURE


SERVE = Command("run the HTTP inference server (GET /health, POST /infer)", _serve_arguments, _serve)
ADAPTER = Command("serve GetActionChunk on ROS 2, forwarding to an inference server", _adapter_arguments, _adapter)
SMOKE_TEST = Command("call a GetActionChunk service once, as ExecutePolicy will, and judge it",
                     _smoke_arguments, _smoke_test)
