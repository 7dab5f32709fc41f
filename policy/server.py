"""The HTTP inference server: one ``PolicyBackend`` behind ``GET /health`` and ``POST /infer``.

Run it as ``objective serve --backend NAME [--replay-file F] [--host H] [--port N]``.
The adapter node (``policy/node.py``) forwards each GetActionChunk call here; the body is
the JSON of ``policy/wire.py`` (no pickle anywhere).

Endpoints:

- ``GET /health``, no token (launchers and probes poll it unauthenticated):
  ``{"status": "loading" | "ready" | "error", "backend": NAME, "message": TEXT}``. ``ready`` only
  once ``backend.load()`` and one full-size ``backend.warmup(example)`` have finished, so the
  caller's own warmup call (which seeds ExecutePolicy's latency estimate, an estimate that only
  grows) never pays for model compilation or cache setup.
- ``POST /infer`` with ``Authorization: Bearer <key>``. Answers, in the order they are checked:
  ``401`` no or wrong key (the answer says nothing about the key; nothing past the headers is
  read, let alone parsed, before the key matches); ``411`` no Content-Length; ``400`` a
  Content-Length that is not ASCII digits, or several that disagree; ``413`` body above ``max_body_bytes`` (refused before it is read); ``503`` still loading, or
  loading failed (with the reason); ``400`` a body that is not a valid request (with the reason);
  ``500`` the backend raised (with its message); ``200`` the backend's answer, which may itself
  be ``status: error`` when the policy understood the problem (a prompt it cannot read).

Security: the key comes from ``POLICY_SERVER_KEY`` and is compared with ``hmac.compare_digest``
(constant time). The server refuses to start without one unless told ``--insecure-no-key``, and
even then only on a loopback address (or with ``--tls-client-ca``, where certificates
authenticate the clients). It binds ``127.0.0.1`` by default: over plain HTTP the key travels in
cleartext, which is only acceptable on loopback; ``exposure_warnings`` says at start what the
configuration exposes. ``--tls-cert/--tls-key`` serve HTTPS instead (``--tls-client-ca``
also requires client certificates) for a server on another machine.

One inference at a time (a lock): backends keep per-episode state and are not thread-safe. The
lock covers the request's decoding too, and at most ``BODIES_AT_ONCE`` bodies are read at a time
(the other clients wait with their bodies unread), so however many large requests arrive,
one thread parses while the rest wait without the GIL: ``GET /health`` never waits for the lock
and answers within a few switch intervals. A request waits for the lock (and for a turn to read
its body) at most ``ServerConfig.lock_wait_s``, then is answered ``503`` busy, so a hung backend
call never piles threads up behind it; a backend call running longer than
``ServerConfig.infer_deadline_s`` is taken for hung: ``/health`` answers ``error`` naming it,
and requests are answered ``503`` at once, until it returns. A request's line and headers must arrive within
``ServerConfig.header_deadline_s`` of its first byte (a client dripping a byte every few seconds is cut off
with a ``408`` before its key is read). Each request is logged on one line with its status and
latency.
"""
from __future__ import annotations

import hmac
import io
import json
import logging
import os
import signal
import socket
import ssl
import sys
import threading
import time
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Callable

import numpy as np

from runtime.errors import OptionError
from runtime.io.interrupt import describe_error, raised_by_code

from .backend import PolicyBackend, PolicyRequest
from .factory import build_backend, is_factory_spec
from .http_client import is_loopback
from .wire import CONTENT_TYPE, DEFAULT_MAX_BODY_BYTES, WireError, decode_request, encode_response, error_body

KEY_ENV = "POLICY_SERVER_KEY"
CELL_JOINTS = (
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
    "wrist_3_joint", "robotiq_85_left_knuckle_joint",
)
"""The simulated cell's observed joints (arm, then gripper): the default warmup observation."""
LOADING, READY, ERROR = "loading", "ready", "error"
SOCKET_TIMEOUT_S = 30.0
"""A client that stops sending mid-body is dropped after this, so it cannot hold a thread forever."""
BODIES_AT_ONCE = 4
"""Request bodies read at the same time (at most this many times ``max_body_bytes`` in memory)."""
DRAIN_S = 2.0

log = logging.getLogger("policy.server")


def execution_horizon(frozen_prefix_steps: int, guidance_horizon: int, default_guidance: int) -> int:
    """LeRobot's ``execution_horizon`` from the request's RTC fields (the guide's conversion).

    ``guidance_horizon`` counts steps past the frozen prefix, ``execution_horizon`` from the
    chunk's start; 0 means "the server's configured width". Both halves matter: adding a zero
    width guides nothing, and passing the width through without the prefix re-decides steps the
    robot is already executing.
    """
    if frozen_prefix_steps < 0 or guidance_horizon < 0 or default_guidance < 0:
        raise OptionError("frozen_prefix_steps, guidance_horizon and default_guidance must be >= 0")
    width = guidance_horizon if guidance_horizon > 0 else default_guidance
    return frozen_prefix_steps + width


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class WarmupSpec:
    """The shape of the startup warmup request: as large as the real ones will be."""

    joint_names: tuple[str, ...] = CELL_JOINTS
    images: tuple[tuple[str, int, int], ...] = (("scene", 224, 224),)
    """``(camera name, height, width)`` per view; frames are RGB uint8."""
    prompt: str = "stack the red cube on the blue cube"

    def request(self) -> PolicyRequest:
        """A mid-gray, zero-joint observation with ``new_episode`` set."""
        return PolicyRequest(
            prompt=self.prompt,
            joint_names=list(self.joint_names),
            joint_positions=np.zeros(len(self.joint_names)),
            images={name: np.full((h, w, 3), 128, dtype=np.uint8) for name, h, w in self.images},
            new_episode=True,
        )


def parse_warmup_images(text: str) -> tuple[tuple[str, int, int], ...]:
    """``"scene=224x224;wrist=480x640"`` (name=HEIGHTxWIDTH, ``;``-separated) -> specs; ValueError."""
    specs = []
    for item in (part.strip() for part in text.split(";")):
        if not item:
            continue
        name, sep, size = item.partition("=")
        height, x, width = size.lower().partition("x")
        if not sep or not name.strip() or not x or not height.isdigit() or not width.isdigit() or not int(height) or not int(width):
            raise OptionError(f"warmup image {item!r}: expected name=HEIGHTxWIDTH, e.g. scene=224x224")
        specs.append((name.strip(), int(height), int(width)))
    return tuple(specs)


@dataclass
class ServerConfig:
    host: str = "127.0.0.1"
    port: int = 0
    """0 picks a free port (read it from ``InferenceServer.url``)."""
    key: str | None = None
    """The bearer key; None only with ``insecure_no_key``."""
    insecure_no_key: bool = False
    max_body_bytes: int = DEFAULT_MAX_BODY_BYTES
    header_deadline_s: float = 10.0
    """Seconds from a request's first byte to the end of its headers; later, ``408`` and closed."""
    lock_wait_s: float = 10.0
    """Seconds a request waits for the inference in progress (one at a time), then ``503`` busy:
    longer than a client waits (the adapter's 2.5 s, ``--policy http``'s 10 s)."""
    infer_deadline_s: float = 30.0
    """Seconds one backend call may run; longer, the backend is taken for hung (``/health``:
    ``error``; ``/infer``: ``503`` at once) until the call returns."""
    warmup: WarmupSpec = field(default_factory=WarmupSpec)
    tls_cert: Path | None = None
    tls_key: Path | None = None
    tls_client_ca: Path | None = None
    """When set, clients must present a certificate signed by this CA (mutual TLS)."""

    def __post_init__(self) -> None:
        if not self.key and not self.insecure_no_key:
            raise OptionError(
                f"no bearer key: set {KEY_ENV} (the adapter sends the same key), or pass "
                "--insecure-no-key to serve /infer to any process on this machine"
            )
        if not self.key and not is_loopback(self.host) and self.tls_client_ca is None:
            raise OptionError(
                f"refusing to serve /infer without a bearer key on {self.host}, which is not a loopback address: "
                f"anyone who can reach the port could drive the robot; set {KEY_ENV}, or require client "
                "certificates (--tls-client-ca), or bind 127.0.0.1"
            )
        if self.max_body_bytes <= 0:
            raise OptionError(f"max_body_bytes must be positive, got {self.max_body_bytes}")
        for name in ("header_deadline_s", "lock_wait_s", "infer_deadline_s"):
            if not 0 < getattr(self, name) < float("inf"):
                raise OptionError(f"{name} must be a positive number of seconds, got {getattr(self, name)}")
        if (self.tls_cert is None) != (self.tls_key is None):
            raise OptionError("--tls-cert and --tls-key go together")
        if self.tls_client_ca is not None and self.tls_cert is None:
            raise OptionError("--tls-client-ca needs --tls-cert and --tls-key")


def exposure_warnings(config: ServerConfig) -> list[str]:
    """What ``objective serve`` warns about at start, each true of ``config`` as given."""
    warnings = []
    if not config.key:
        who = "any process on this machine" if is_loopback(config.host) else "any client with a certificate from --tls-client-ca"
        warnings.append(f"serving /infer without a bearer key (--insecure-no-key): {who} can call the policy")
    if not is_loopback(config.host) and config.tls_cert is None:
        warnings.append(f"serving plain HTTP on {config.host}: the bearer key and every observation travel in "
                        "cleartext; use TLS (--tls-cert/--tls-key) or a private network")
    return warnings


# --------------------------------------------------------------------------------------------
# The server
# --------------------------------------------------------------------------------------------
@dataclass
class Reply:
    code: int
    body: bytes
    note: str = ""
    """What the request log line says after the status (the answer's status or error)."""


class InferenceServer:
    """A backend served over HTTP. ``start()`` binds, serves and loads in background threads."""

    def __init__(self, backend: PolicyBackend, config: ServerConfig) -> None:
        self.backend = backend
        self.config = config
        self.backend_name = str(getattr(backend, "name", type(backend).__name__))
        self.status = LOADING
        self.message = "loading the backend"
        self.requests = 0
        self._infer_lock = threading.Lock()
        self._infer_started_s: float | None = None
        """``time.monotonic()`` when the backend call in progress started (None: none runs)."""
        self.intake = threading.BoundedSemaphore(BODIES_AT_ONCE)
        self._httpd: ThreadingHTTPServer | None = None
        self._port: int | None = None
        self._threads: list[threading.Thread] = []
        self.ready = threading.Event()
        """Set once the status leaves ``loading`` (ready or error)."""

    # -- lifecycle ---
    def start(self) -> InferenceServer:
        """Bind (the port is known when this returns), serve, and load + warm up the backend."""
        self._httpd = _make_httpd(self)
        self._port = int(self._httpd.server_address[1])
        serve = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.1},
                                 name="inference-server", daemon=True)
        load = threading.Thread(target=self._load, name="inference-server-load", daemon=True)
        self._threads = [serve, load]
        serve.start()
        load.start()
        return self

    @property
    def port(self) -> int:
        assert self._port is not None, "start() first"
        return self._port

    @property
    def url(self) -> str:
        scheme = "https" if self.config.tls_cert else "http"
        host = self.config.host
        host = f"[{host}]" if ":" in host else host
        return f"{scheme}://{host}:{self.port}"

    def stop(self) -> None:
        """Stop accepting, finish the requests in flight, close the socket. Idempotent."""
        httpd, self._httpd = self._httpd, None
        if httpd is None:
            return
        httpd.shutdown()
        httpd.server_close()
        close = getattr(self.backend, "close", None)
        if callable(close):
            close()

    def _load(self) -> None:
        started = time.monotonic()
        try:
            self.backend.load()
            self.message = "warming up"
            loaded = time.monotonic()
            with self._infer_lock:
                self.backend.warmup(self.config.warmup.request())
            self.message = f"loaded in {loaded - started:.2f} s, warmup took {time.monotonic() - loaded:.2f} s"
            self.status = READY
            log.info("backend '%s' ready (%s)", self.backend_name, self.message)
        except Exception as exc:
            self.message = f"backend '{self.backend_name}' failed to load: {type(exc).__name__}: {exc}"
            self.status = ERROR
            log.error("%s", self.message)
        finally:
            self.ready.set()

    # -- endpoints (pure of HTTP plumbing, so tests and the handler share them) ---
    def health(self) -> Reply:
        status, message = self.status, self.message
        stalled = self.stalled()
        if status == READY and stalled is not None:
            status, message = ERROR, stalled
        body = {"status": status, "backend": self.backend_name, "message": message}
        return Reply(200, json.dumps(body).encode("utf-8"), status)

    def running_s(self) -> float:
        """How long the backend call in progress has run (0 when none runs)."""
        started = self._infer_started_s
        return 0.0 if started is None else time.monotonic() - started

    def stalled(self) -> str | None:
        """Why the backend is taken for hung (its call in progress is over ``infer_deadline_s``), or None."""
        running_s = self.running_s()
        if running_s <= self.config.infer_deadline_s:
            return None
        return (f"backend '{self.backend_name}' has been in one inference for {running_s:.1f} s, over its deadline "
                f"of {self.config.infer_deadline_s:g} s: it looks hung (restart the server)")

    def busy(self) -> Reply:
        """The answer to a request that waited ``lock_wait_s`` for its turn."""
        return _error(503, f"policy server is busy: it runs one inference at a time, the one in progress has run "
                           f"for {self.running_s():.1f} s and this request waited {self.config.lock_wait_s:g} s; try again")

    def authorized(self, header: str | None) -> bool:
        """Is ``header`` ``Bearer <the key>``? Constant-time; always true with no key configured."""
        if not self.config.key:
            return True
        scheme, _, token = (header or "").partition(" ")
        if scheme.lower() != "bearer":
            return False
        return hmac.compare_digest(token.strip().encode("utf-8"), self.config.key.encode("utf-8"))

    def infer(self, body: bytes) -> Reply:
        """Decode and run the backend, one request at a time; encode."""
        if self.status != READY:
            return _error(503, f"policy server is not ready: {self.message}" if self.status == ERROR
                          else f"policy server is still loading ({self.message})")
        stalled = self.stalled()
        if stalled is not None:
            return _error(503, f"policy server is not ready: {stalled}")
        if not self._infer_lock.acquire(timeout=self.config.lock_wait_s):
            return self.busy()
        try:
            try:
                request = decode_request(body)
            except WireError as exc:
                return _error(400, f"bad request: {exc}")
            self.requests += 1
            self._infer_started_s = time.monotonic()
            try:
                response = self.backend.infer(request)
            except BaseException as exc:  # sys.exit() and KeyboardInterrupt in a policy's code are its errors too
                if not raised_by_code(exc):
                    raise
                return _error(500, f"policy backend '{self.backend_name}' failed: {describe_error(exc)}")
            finally:
                self._infer_started_s = None
        finally:
            self._infer_lock.release()
        try:
            return Reply(200, encode_response(response), getattr(response.status, "value", "?"))
        except WireError as exc:
            return _error(500, f"policy backend '{self.backend_name}' returned an invalid answer: {exc}")


def content_length(values: list[str]) -> int | str | None:
    """The body length the ``Content-Length`` header(s) declare: an int, None when absent, or the
    reason it is malformed (not ASCII digits, or several headers that disagree)."""
    if not values:
        return None
    texts = {value.strip() for value in values}
    if len(texts) > 1:
        return f"Content-Length is given {len(values)} times with different values"
    [text] = texts
    if not (text.isascii() and text.isdigit()) or len(text) > 18:
        return f"Content-Length must be a number of bytes, got {text[:40]!r}"
    return int(text)


def _error(code: int, reason: str) -> Reply:
    return Reply(code, error_body(reason), reason)


class _DeadlineReader(io.RawIOBase):
    """The connection's bytes, read with a deadline: ``start_deadline`` bounds the time until
    ``clear_deadline`` (the headers of one request); otherwise each read waits at most
    ``SOCKET_TIMEOUT_S``. ``TimeoutError`` when time is up."""

    def __init__(self, sock: socket.socket) -> None:
        super().__init__()
        self.sock = sock
        self.deadline: float | None = None
        self.expired = False

    def readable(self) -> bool:
        return True

    def start_deadline(self, seconds: float) -> None:
        self.deadline, self.expired = time.monotonic() + seconds, False

    def clear_deadline(self) -> None:
        self.deadline, self.expired = None, False

    def readinto(self, buffer: Any) -> int:
        wait = SOCKET_TIMEOUT_S
        if self.deadline is not None:
            wait = min(wait, self.deadline - time.monotonic())
            if wait <= 0:
                self.expired = True
                raise TimeoutError("the request's headers did not arrive in time")
        self.sock.settimeout(wait)
        try:
            return self.sock.recv_into(buffer)
        except TimeoutError:
            self.expired = self.deadline is not None
            raise


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    default_request_version = "HTTP/1.0"
    """A request line too broken to name a version is answered with a status line (HTTP/0.9
    answers have none, so the client would see a bare page instead of a 400)."""
    timeout = SOCKET_TIMEOUT_S
    server_version = "objective-inference/1"
    app: InferenceServer  # set on the per-server subclass

    def setup(self) -> None:
        super().setup()
        self.reader = _DeadlineReader(self.connection)
        self.rfile: io.BufferedReader = io.BufferedReader(self.reader)

    def handle_one_request(self) -> None:
        """One request; its line and headers must arrive within ``header_deadline_s`` of its
        first byte (an idle keep-alive connection waits up to ``SOCKET_TIMEOUT_S`` as before)."""
        self.reader.clear_deadline()
        try:
            self.rfile.peek(1)  # the first byte of the next request (or the end of the connection)
        except (TimeoutError, OSError):
            self.close_connection = True
            return
        self.reader.start_deadline(self.app.config.header_deadline_s)
        super().handle_one_request()
        if self.reader.expired:
            self.close_connection = True
            reason = f"the request line and headers did not arrive within {self.app.config.header_deadline_s:g} s"
            body = error_body(reason)
            head = (f"HTTP/1.1 408 Request Timeout\r\nContent-Type: {CONTENT_TYPE}\r\nContent-Length: {len(body)}\r\n"
                    "Connection: close\r\n\r\n")
            try:
                self.wfile.write(head.encode("ascii") + body)
            except OSError:
                pass
            log.info("%s request timed out: %s", self.address_string(), reason)

    def parse_request(self) -> bool:
        """http.server's parsing; the headers are in, so the body is read without the deadline."""
        parsed = super().parse_request()
        self.reader.clear_deadline()
        return parsed

    def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
        started = time.monotonic()
        if self.path.split("?", 1)[0] == "/health":
            reply = self.app.health()
        else:
            reply = _error(404, f"no such endpoint {self.path!r} (GET /health, POST /infer)")
        self._send(reply, started)

    def do_POST(self) -> None:  # noqa: N802
        started = time.monotonic()
        length = content_length(self.headers.get_all("Content-Length") or [])
        drain = length if isinstance(length, int) else None
        limit = self.app.config.max_body_bytes
        if self.path.split("?", 1)[0] != "/infer":
            return self._refuse(_error(404, f"no such endpoint {self.path!r} (GET /health, POST /infer)"), started, drain)
        if not self.app.authorized(self.headers.get("Authorization")):
            return self._refuse(_error(401, "unauthorized: send Authorization: Bearer <key>"), started, drain,
                                authenticate=True)
        if length is None:
            return self._refuse(_error(411, "a Content-Length header is required"), started, None)
        if isinstance(length, str):
            return self._refuse(_error(400, length), started, None)
        if length > limit:
            reason = f"request body of {length} bytes exceeds the limit of {limit} bytes"
            return self._refuse(_error(413, reason), started, length)
        if not self.app.intake.acquire(timeout=self.app.config.lock_wait_s):  # BODIES_AT_ONCE wait for the lock
            return self._refuse(self.app.busy(), started, length)
        try:
            body = self.rfile.read(length)
            if len(body) != length:
                self.close_connection = True
                return self._send(_error(400, f"request body ended after {len(body)} of {length} bytes"), started)
            try:
                reply = self.app.infer(body)
            except Exception as exc:  # a bug here must still answer, never drop the connection
                log.exception("POST /infer failed")
                reply = _error(500, f"policy server failed: {type(exc).__name__}: {exc}")
        finally:
            self.app.intake.release()
        self._send(reply, started)

    def _refuse(self, reply: Reply, started: float, length: int | None, authenticate: bool = False) -> None:
        """Answer without using the body, then close the connection.

        The unread body is drained first (at most ``2 * max_body_bytes``, for at most
        ``DRAIN_S`` seconds): closing a socket with unread data makes the kernel send a reset,
        which can destroy the answer before the client reads it, leaving it a bare "connection
        reset" instead of the reason.
        """
        self.close_connection = True
        self._send(reply, started, authenticate)
        if not length:
            return
        budget = min(length, 2 * self.app.config.max_body_bytes)
        self.reader.start_deadline(DRAIN_S)
        try:
            while budget > 0:
                piece = self.rfile.read1(min(budget, 1 << 16))
                if not piece:
                    break
                budget -= len(piece)
        except OSError:  # TimeoutError included: DRAIN_S is over
            pass
        finally:
            self.reader.clear_deadline()

    def _send(self, reply: Reply, started: float, authenticate: bool = False) -> None:
        self.send_response(reply.code)
        self.send_header("Content-Type", CONTENT_TYPE)
        self.send_header("Content-Length", str(len(reply.body)))
        if authenticate:
            self.send_header("WWW-Authenticate", "Bearer")
        if self.close_connection:
            self.send_header("Connection", "close")
        self.end_headers()
        self.wfile.write(reply.body)
        latency_ms = (time.monotonic() - started) * 1000
        log.info("%s %s %d %.1f ms %s", self.command, self.path, reply.code, latency_ms, reply.note[:160])

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (http.server's signature)
        """Silence http.server's own access log: ``_send`` logs one line per request."""

    def log_error(self, format: str, *args: Any) -> None:  # noqa: A002
        log.warning("%s: %s", self.address_string(), format % args)


def _make_httpd(app: InferenceServer) -> ThreadingHTTPServer:
    config = app.config
    handler = type("InferenceHandler", (_Handler,), {"app": app})

    class Server(ThreadingHTTPServer):
        address_family = socket.AF_INET6 if ":" in config.host else socket.AF_INET
        daemon_threads = True
        allow_reuse_address = True
        request_queue_size = 64  # connections the kernel holds while the accepting thread waits for the GIL

        def handle_error(self, request: Any, client_address: Any) -> None:
            """One log line, not socketserver's traceback on stderr (a client that hung up)."""
            exc = sys.exc_info()[1]
            log.warning("%s: connection ended: %s: %s", client_address[0], type(exc).__name__, exc)

    httpd = Server((config.host, config.port), handler)
    if config.tls_cert is not None:
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        context.load_cert_chain(str(config.tls_cert), str(config.tls_key))
        if config.tls_client_ca is not None:
            context.load_verify_locations(cafile=str(config.tls_client_ca))
            context.verify_mode = ssl.CERT_REQUIRED
        httpd.socket = context.wrap_socket(httpd.socket, server_side=True)
    return httpd


# --------------------------------------------------------------------------------------------
# Backends by name
# --------------------------------------------------------------------------------------------
@dataclass
class BackendOptions:
    """What ``objective serve`` knows about the backend it should build."""

    replay_file: Path | None = None
    default_guidance: int = 0
    """The server's RTC guidance width (``guidance_horizon`` 0 means this), for denoising backends."""
    checkpoint: Path | None = None
    """A LeRobot checkpoint directory (``--backend lerobot``)."""
    noise_scale: float | None = None
    """Scale of a denoising policy's starting noise (``--noise-scale``); None: the checkpoint's own."""


def replay_backend(options: BackendOptions) -> PolicyBackend:
    """``--backend replay``: the chunks of ``--replay-file``, in order."""
    from .replay import ReplayBackend

    if options.replay_file is None:
        raise OptionError("--backend replay needs --replay-file FILE (chunks as JSON lines)")
    if not options.replay_file.is_file():
        raise OptionError(f"--replay-file {options.replay_file}: no such file")
    return ReplayBackend(options.replay_file)


def lerobot_backend(options: BackendOptions) -> PolicyBackend:
    """``--backend lerobot``: the LeRobot checkpoint in ``--checkpoint`` (needs `make lerobot`)."""
    from .lerobot_backend import make_lerobot_backend

    if options.checkpoint is None:
        raise OptionError("--backend lerobot needs --checkpoint DIR (a LeRobot checkpoint folder)")
    if not options.checkpoint.is_dir():
        raise OptionError(f"--checkpoint {options.checkpoint}: no such directory")
    return make_lerobot_backend(options.checkpoint, guidance_horizon=options.default_guidance or None,
                                noise_scale=options.noise_scale)


BACKEND_GROUP = "objective.policy_backends"
"""Entry-point group naming the ``--backend`` choices: name -> ``factory(BackendOptions)``. This
package declares ``replay`` and ``lerobot``; the simulated cell declares ``oracle``; a new backend
is one class with ``load`` / ``warmup`` / ``infer`` and one entry point, nothing else changes."""


def backend_names() -> list[str]:
    return sorted({ep.name for ep in entry_points(group=BACKEND_GROUP)})


def make_backend(name: str, options: BackendOptions) -> PolicyBackend:
    """The backend ``name`` (an installed one, or your own factory ``FILE.py:NAME`` /
    ``MODULE:NAME``, see ``policy.factory``) built from ``options``; ValueError saying what is wrong."""
    found = [ep for ep in entry_points(group=BACKEND_GROUP) if ep.name == name]
    if not found and is_factory_spec(name):
        return build_backend(name, options)
    if not found:
        raise OptionError(f"unknown backend {name!r} (known: {', '.join(backend_names()) or 'none installed'}; "
                          "or your own factory as FILE.py:NAME or MODULE:NAME)")
    factory: Callable[[BackendOptions], PolicyBackend] = found[0].load()
    return factory(options)


def key_from_env(environ: dict[str, str] | None = None) -> str | None:
    """The bearer key in ``POLICY_SERVER_KEY`` (None when unset or blank)."""
    value = (os.environ if environ is None else environ).get(KEY_ENV, "").strip()
    return value or None


def stop_on_signals(stop: threading.Event) -> Callable[[], None]:
    """Set ``stop`` on SIGINT/SIGTERM (main thread only); returns a function restoring the handlers.

    Installed before rclpy's handlers (a backend or node that joins ROS 2 installs those), which
    shut their contexts down and then call these.
    """
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in previous:
        signal.signal(sig, lambda signum, frame: stop.set())

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore


def serve_forever(server: InferenceServer, stop: threading.Event) -> None:
    """Run ``server`` until ``stop`` is set (the CLI sets it on SIGINT/SIGTERM), then stop it."""
    server.start()
    print(f"listening on {server.url}", flush=True)
    for warning in exposure_warnings(server.config):
        log.warning("%s", warning)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        server.stop()
        log.info("stopped after %d inference requests", server.requests)
