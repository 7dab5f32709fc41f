"""The adapter with its HTTP backend: forwarding, every failure answered as ERROR (quickly), the
infer_url policy (loopback or verified TLS), and the adapter node as a real ROS 2 process."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest
from moveit_pro_ml_msgs.srv import GetActionChunk

from runtime.io.bus import InProcessBus
from runtime.io.clock import SimClock
from policy.adapter import request_to_msg
from policy.backend import PolicyRequest, PolicyResponse
from policy.http_client import ClientConfig, HttpBackend, InferUrlError, check_infer_url, redact_url
from policy.images import rgb_to_image
from policy.node import AdapterConfig, http_adapter
from policy.replay import RecordedChunk, write_replay
from policy.server import CELL_JOINTS, KEY_ENV, InferenceServer, ServerConfig
from policy.replay import ReplayBackend

from .fakes import FakeBackend

pytestmark = pytest.mark.timeout(60)

KEY = "adapter-test-key"
ROOT = Path(__file__).resolve().parents[1]
R = GetActionChunk.Response
JOINTS = list(CELL_JOINTS)


def Recorder(answer=None, gate: threading.Event | None = None) -> FakeBackend:  # noqa: N802 (reads like the class it was)
    """A server backend that keeps every request and answers ``answer(request)`` (by default 5
    steps holding the observed joints); with ``gate``, each answer waits for it."""
    default = lambda r: PolicyResponse.chunk(np.tile(r.joint_positions, (5, 1)), 0.1)  # noqa: E731
    return FakeBackend(answer or default, infer_gate=gate, name="recorder")


@pytest.fixture
def serve():
    started: list[InferenceServer] = []

    def start(backend, **config) -> InferenceServer:
        config.setdefault("key", KEY)
        server = InferenceServer(backend, ServerConfig(host="127.0.0.1", port=0, **config)).start()
        started.append(server)
        assert server.ready.wait(10)
        return server

    yield start
    for server in started:
        server.stop()


def request_msg(**fields) -> GetActionChunk.Request:
    values = dict(prompt="stack the red cube on the blue cube", joint_names=JOINTS,
                  joint_positions=np.linspace(-1.0, 1.0, len(JOINTS)), new_episode=True, stamp=4.5)
    values.update(fields)
    return request_to_msg(PolicyRequest(**values))


def call_in_process(url: str, msg: GetActionChunk.Request, **config) -> tuple[GetActionChunk.Response, float, object]:
    """Serve the HTTP adapter on an InProcessBus and call it once: (response, wall seconds, adapter)."""
    config.setdefault("key", KEY)
    clock = SimClock()
    bus = InProcessBus(clock)
    adapter = http_adapter(AdapterConfig(infer_url=url, **config)).serve(bus)
    client = bus.create_client("/get_action_chunk", GetActionChunk)
    started = time.monotonic()
    future = client.call_async(msg)
    elapsed = time.monotonic() - started
    clock.advance(30.0)
    bus.spin_once()
    bus.close()  # the service's worker thread ends with the bus
    assert future.done()
    return future.result(), elapsed, adapter


# --------------------------------------------------------------------------------------------
# Forwarding
# --------------------------------------------------------------------------------------------
def test_replay_server_chunk_reaches_the_caller(serve, tmp_path):
    replay = tmp_path / "r.jsonl"
    actions = np.arange(35, dtype=float).reshape(5, 7) / 100
    write_replay(replay, [RecordedChunk(JOINTS, actions, 0.1)])
    server = serve(ReplayBackend(replay))
    response, _, adapter = call_in_process(server.url, request_msg())
    assert response.status == R.CHUNK_PRODUCED, response.message
    assert list(response.chunk.joint_names) == JOINTS
    assert np.array_equal([list(p.positions) for p in response.chunk.points], actions)
    assert response.native_control_period == 0.1
    assert adapter.served_chunks == 1
    # the replay ends its stream: that is the source's choice, passed through
    response, _, _ = call_in_process(server.url, request_msg(new_episode=False))
    assert (response.status, response.message) == (R.NO_MORE_ACTIONS, "replay of 'r.jsonl' finished after 1 chunks")


def test_every_request_field_is_forwarded_exactly(serve):
    recorder = Recorder(lambda r: PolicyResponse.chunk(np.zeros((3, 7)), 0.1, np.ones((3, 32))))
    server = serve(recorder)
    rng = np.random.default_rng(5)
    scene = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    msg = request_msg(
        images={"scene": scene},
        previous_action_chunk=rng.normal(size=(12, 32)),
        previous_anchor_positions=rng.normal(size=7),
        frozen_prefix_steps=4,
        guidance_horizon=6,
        new_episode=False,
    )
    msg.images = [rgb_to_image(scene, "bgr8")]  # frames arrive as captured; the adapter converts
    response, _, _ = call_in_process(server.url, msg)
    assert response.status == R.CHUNK_PRODUCED, response.message
    [got] = recorder.requests
    assert np.array_equal(got.images["scene"], scene)
    assert got.joint_names == JOINTS and np.array_equal(got.joint_positions, np.linspace(-1, 1, 7))
    assert np.array_equal(got.previous_action_chunk, np.asarray(msg.previous_action_chunk.data).reshape(12, 32))
    assert np.array_equal(got.previous_anchor_positions, np.asarray(msg.previous_anchor_state.position))
    assert (got.frozen_prefix_steps, got.guidance_horizon, got.new_episode, got.stamp) == (4, 6, False, 4.5)
    assert [d.size for d in response.policy_action_chunk.layout.dim] == [3, 32]
    assert response.policy_action_chunk.layout.data_offset == 0


# --------------------------------------------------------------------------------------------
# Failures are ERROR with a reason, never NO_MORE_ACTIONS, never a hang
# --------------------------------------------------------------------------------------------
def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # wall-clock time
def test_server_down_answers_error_quickly():
    port = _free_port()
    response, elapsed, adapter = call_in_process(f"http://127.0.0.1:{port}", request_msg())
    assert response.status == R.ERROR
    assert response.message == (
        f"cannot reach the inference server at http://127.0.0.1:{port}/infer: "
        "connection refused (is the server running, on this port?)"
    )
    assert elapsed < 1.0
    assert (adapter.errors, adapter.served_chunks) == (1, 0)


@pytest.mark.slow  # wall-clock time
def test_slow_server_answers_error_at_the_timeout(serve):
    gate = threading.Event()
    server = serve(Recorder(gate=gate))
    try:
        response, elapsed, _ = call_in_process(server.url, request_msg(), timeout=0.3)
    finally:
        gate.set()
    assert response.status == R.ERROR
    assert response.message == f"the inference server at {server.url}/infer did not answer within 0.3 s"
    assert 0.3 <= elapsed < 1.0


@pytest.mark.parametrize("case, reason", [
    ("wrong key", "answered 401: unauthorized: send Authorization: Bearer <key>"),
    ("model error", "answered 500: policy backend 'recorder' failed: RuntimeError: weights are NaN"),
    ("too large", "answered 413: request body of"),
])
def test_http_errors_answer_error_with_the_servers_reason(serve, case, reason):
    def boom(request):
        raise RuntimeError("weights are NaN")

    server = serve(Recorder(boom if case == "model error" else None), max_body_bytes=4096 if case == "too large" else 1 << 25)
    images = {"scene": np.zeros((64, 64, 3), dtype=np.uint8)} if case == "too large" else {}
    response, elapsed, _ = call_in_process(server.url, request_msg(images=images),
                                           key="not-the-key" if case == "wrong key" else KEY)
    assert response.status == R.ERROR
    assert response.message.startswith(f"the inference server at {server.url}/infer {reason}"), response.message


def test_server_still_loading_answers_error_503(serve):
    slow_load = FakeBackend(gated=True)  # loads only once released
    server = InferenceServer(slow_load, ServerConfig(key=KEY)).start()
    try:
        response, _, _ = call_in_process(server.url, request_msg())
    finally:
        slow_load.release.set()
        server.stop()
    assert response.status == R.ERROR
    assert response.message == f"the inference server at {server.url}/infer answered 503: policy server is still loading (loading the backend)"


def test_invalid_chunk_from_the_server_is_an_error(serve):
    server = serve(Recorder(lambda r: PolicyResponse.chunk(np.zeros((5, 3)), 0.1)))
    response, _, _ = call_in_process(server.url, request_msg())
    assert response.status == R.ERROR
    assert response.message == "policy backend 'http' returned an invalid answer: chunk has 3 columns for 7 observed joints " \
        f"[{', '.join(JOINTS)}]"


def test_malformed_body_is_an_error():
    class Garbage(BaseHTTPRequestHandler):
        def do_POST(self):  # noqa: N802
            self.rfile.read(int(self.headers["Content-Length"]))
            body = b"<html>gateway says hi</html>"
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Garbage)
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{httpd.server_address[1]}"
        response, _, _ = call_in_process(url, request_msg())
    finally:
        httpd.shutdown()
        httpd.server_close()
    assert response.status == R.ERROR
    assert response.message.startswith(f"the inference server at {url}/infer sent a malformed answer: response body is not valid JSON")


# --------------------------------------------------------------------------------------------
# infer_url policy
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("url, expected", [
    ("http://127.0.0.1:8000", "http://127.0.0.1:8000/infer"),
    ("http://127.0.0.1:8000/infer", "http://127.0.0.1:8000/infer"),
    ("http://127.3.4.5:8000/v1/infer", "http://127.3.4.5:8000/v1/infer"),
    ("http://localhost:9", "http://localhost:9/infer"),
    ("http://[::1]:8000/", "http://[::1]:8000/infer"),
    ("https://10.1.2.3:8443", "https://10.1.2.3:8443/infer"),
    ("https://gpu.example.com/policy/infer", "https://gpu.example.com:443/policy/infer"),
])
def test_accepted_infer_urls(url, expected):
    endpoint = check_infer_url(url)
    assert endpoint.url == expected
    assert endpoint.health_url == expected.removesuffix("/infer") + "/health"


@pytest.mark.parametrize("url, reason", [
    ("http://10.1.2.3:8000", "refusing plain http to 10.1.2.3, which is not a loopback address"),
    ("http://gpu.example.com", "refusing plain http to gpu.example.com, which is not a loopback address"),
    ("http://0.0.0.0:8000", "refusing plain http to 0.0.0.0"),
    ("ftp://127.0.0.1/infer", "must start with http:// (loopback only) or https://"),
    ("127.0.0.1:8000", "must start with http:// (loopback only) or https://"),
    ("http://user:pw@127.0.0.1:8000", "must not carry credentials"),
    ("http://127.0.0.1:99999", "is not a valid URL"),
])
def test_refused_infer_urls(url, reason):
    with pytest.raises(InferUrlError, match=reason.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        check_infer_url(url)


@pytest.mark.parametrize("url, shown", [
    ("http://user:s3cret@127.0.0.1:8000", "http://***@127.0.0.1:8000"),
    ("https://user:p@ss:w/rd@gpu.example.com/infer", "https://***@gpu.example.com/infer"),
    ("user:s3cret@127.0.0.1:8000", "***@127.0.0.1:8000"),
    ("http://127.0.0.1:8000/infer?token=s3cret#s3cret", "http://127.0.0.1:8000/infer?***"),
    ("http://127.0.0.1:8000/infer", "http://127.0.0.1:8000/infer"),
])
def test_urls_are_printed_without_their_secrets(url, shown):
    assert redact_url(url) == shown


@pytest.mark.parametrize("url", [
    "http://user:s3cret@127.0.0.1:8000", "http://user:s3cret@10.0.0.5:8000", "ftp://user:s3cret@127.0.0.1",
    "user:s3cret@127.0.0.1:8000", "http://user:s3cret@127.0.0.1:99999", "https://127.0.0.1/infer?key=s3cret",
])
def test_the_adapter_never_echoes_a_password_from_its_url(url, capsys):
    from runtime.app.cli import main

    assert main(["adapter", "--infer-url", url]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "s3cret" not in err, err


def test_tls_files_need_https(tmp_path):
    ca = tmp_path / "ca.pem"
    ca.write_text("x")
    with pytest.raises(InferUrlError, match="a CA file or client certificate was given for a plain http:// infer_url"):
        HttpBackend(ClientConfig("http://127.0.0.1:8000", ca_file=ca))
    with pytest.raises(InferUrlError, match="CA file .*missing.pem: no such file"):
        HttpBackend(ClientConfig("https://127.0.0.1:8000", ca_file=tmp_path / "missing.pem"))


def test_adapter_command_refuses_a_remote_plain_http_url_at_start_up():
    proc = subprocess.run([sys.executable, "-m", "runtime.app.cli", "adapter", "--infer-url", "http://10.1.2.3:8000"],
                          cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert "error: refusing plain http to 10.1.2.3, which is not a loopback address" in proc.stderr
    assert "serving" not in proc.stdout


# --------------------------------------------------------------------------------------------
# HTTPS with verification (and client certificates)
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """A throwaway CA, a server certificate for 127.0.0.1 and a client certificate (openssl CLI)."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    d = tmp_path_factory.mktemp("pki")
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]

    def run(*args):
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True, timeout=30)

    run("req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", "2", "-subj", "/CN=test CA")
    (d / "server.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    for name in ("server", "client"):
        run("req", *ec, "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}")
        extra = ["-extfile", "server.ext"] if name == "server" else []
        run("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-out", f"{name}.pem", "-days", "2", *extra)
    return d


def test_https_with_the_ca_verifies_and_serves(serve, pki):
    server = serve(Recorder(), tls_cert=pki / "server.pem", tls_key=pki / "server.key")
    assert server.url.startswith("https://127.0.0.1:")
    response, _, _ = call_in_process(server.url, request_msg(), ca_file=pki / "ca.pem")
    assert response.status == R.CHUNK_PRODUCED, response.message


def test_https_with_an_unknown_ca_is_refused(serve, pki):
    server = serve(Recorder(), tls_cert=pki / "server.pem", tls_key=pki / "server.key")
    response, elapsed, _ = call_in_process(server.url, request_msg())
    assert response.status == R.ERROR
    assert response.message.startswith(
        f"cannot reach the inference server at {server.url}/infer: TLS certificate verification failed"
    ), response.message


def test_mutual_tls_needs_the_client_certificate(serve, pki):
    server = serve(Recorder(), tls_cert=pki / "server.pem", tls_key=pki / "server.key", tls_client_ca=pki / "ca.pem")
    without, _, _ = call_in_process(server.url, request_msg(), ca_file=pki / "ca.pem")
    assert without.status == R.ERROR
    assert without.message.startswith(f"cannot reach the inference server at {server.url}/infer")
    with_cert, _, _ = call_in_process(server.url, request_msg(), ca_file=pki / "ca.pem",
                                      client_cert=pki / "client.pem", client_key=pki / "client.key")
    assert with_cert.status == R.CHUNK_PRODUCED, with_cert.message


# --------------------------------------------------------------------------------------------
# The adapter node: a separate process on real ROS 2
# --------------------------------------------------------------------------------------------
@pytest.mark.ros
@pytest.mark.timeout(60)
def test_adapter_node_process_serves_over_ros2_and_stops_on_sigterm(serve):
    import uuid

    from runtime.io.clock import WallClock
    from runtime.io.ros import RosBus

    recorder = Recorder()
    server = serve(recorder)
    service = f"/t{uuid.uuid4().hex[:8]}/get_action_chunk"
    env = {**os.environ, KEY_ENV: KEY, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "runtime.app.cli", "adapter", "--infer-url", server.url, "--service-name", service],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    bus = RosBus(WallClock(), node_name="adapter_test_caller")
    try:
        line = proc.stdout.readline()
        assert line.strip() == f"serving {service} -> {server.url}/infer", line + proc.stderr.read()
        client = bus.create_client(service, GetActionChunk)
        deadline = time.monotonic() + 10
        while not client.service_is_ready() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert client.service_is_ready()
        future = client.call_async(request_msg())
        deadline = time.monotonic() + 10
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        response = future.result()
        assert response.status == R.CHUNK_PRODUCED, response.message
        assert list(response.chunk.joint_names) == JOINTS
        assert len(response.chunk.points) == 5
        assert recorder.requests[0].stamp == 4.5

        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        err = proc.stderr.read()
        assert "served 1 chunks" in err
        assert "stopped: served 1 chunks, answered 0 errors in 1 calls" in err
    finally:
        bus.close()
        proc.kill()
        proc.wait()
