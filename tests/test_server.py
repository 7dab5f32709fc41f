"""The HTTP inference server: health lifecycle, bearer key, 400/413/503/500 answers, the wire format,
the `objective serve` process, and the oracle backend's privileged view over ROS 2."""
from __future__ import annotations

import base64
import http.client
import json
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from policy.backend import PolicyRequest, PolicyResponse, PolicyStatus
from policy.replay import RecordedChunk, write_replay
from policy.server import (
    CELL_JOINTS,
    KEY_ENV,
    InferenceServer,
    ServerConfig,
    WarmupSpec,
    execution_horizon,
    exposure_warnings,
    parse_warmup_images,
)
from policy.wire import (
    WireError,
    decode_request,
    decode_response,
    encode_array,
    encode_request,
    encode_response,
)

from .fakes import FakeBackend

pytestmark = pytest.mark.timeout(60)

KEY = "test-key-0123456789"
ROOT = Path(__file__).resolve().parents[1]


def chunk_answer(request: PolicyRequest) -> PolicyResponse:
    steps = 4
    return PolicyResponse.chunk(np.tile(request.joint_positions, (steps, 1)) + 0.01, 0.1)


def observation(**fields) -> PolicyRequest:
    values = dict(
        prompt="stack the red cube on the blue cube",
        joint_names=list(CELL_JOINTS),
        joint_positions=np.linspace(-1, 1, len(CELL_JOINTS)),
        images={"scene": np.arange(8 * 6 * 3, dtype=np.uint8).reshape(8, 6, 3)},
        new_episode=True,
        stamp=12.5,
    )
    values.update(fields)
    return PolicyRequest(**values)


@pytest.fixture
def serve():
    """Start servers on 127.0.0.1 with a free port; every one is stopped at the end."""
    started: list[InferenceServer] = []

    def start(backend, wait_ready: bool = True, **config) -> InferenceServer:
        config.setdefault("key", KEY)
        server = InferenceServer(backend, ServerConfig(host="127.0.0.1", port=0, **config)).start()
        started.append(server)
        if wait_ready:
            assert server.ready.wait(10), "server never finished loading"
        return server

    yield start
    for server in started:
        server.stop()


def call(server: InferenceServer, method: str, path: str, body: bytes | None = None, key: str | None = KEY,
         headers: dict | None = None) -> tuple[int, dict, dict]:
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
    try:
        all_headers = dict(headers or {})
        if key is not None:
            all_headers["Authorization"] = f"Bearer {key}"
        conn.request(method, path, body=body, headers=all_headers)
        response = conn.getresponse()
        payload = response.read()
        return response.status, json.loads(payload), dict(response.getheaders())
    finally:
        conn.close()


# --------------------------------------------------------------------------------------------
# Health and loading
# --------------------------------------------------------------------------------------------
def test_health_goes_loading_then_ready_after_a_full_size_warmup(serve):
    backend = FakeBackend(chunk_answer, gated=True)
    server = serve(backend, wait_ready=False, warmup=WarmupSpec(images=(("scene", 224, 224), ("wrist", 120, 160))))

    code, health, _ = call(server, "GET", "/health", key=None)
    assert (code, health["status"], health["backend"]) == (200, "loading", "fake")
    code, body, _ = call(server, "POST", "/infer", encode_request(observation()))
    assert code == 503
    assert body["error"].startswith("policy server is still loading")
    assert backend.requests == []

    backend.release.set()
    assert server.ready.wait(5)
    code, health, _ = call(server, "GET", "/health", key=None)
    assert (code, health["status"]) == (200, "ready")
    assert "warmup took" in health["message"]
    [example] = backend.warmups
    assert example.joint_names == list(CELL_JOINTS)
    assert {name: image.shape for name, image in example.images.items()} == {"scene": (224, 224, 3), "wrist": (120, 160, 3)}
    assert example.new_episode


def test_load_failure_reports_error_and_infer_answers_503_with_the_reason(serve):
    server = serve(FakeBackend(load_error=FileNotFoundError("checkpoint.safetensors")))
    code, health, _ = call(server, "GET", "/health", key=None)
    assert health["status"] == "error"
    assert health["message"] == "backend 'fake' failed to load: FileNotFoundError: checkpoint.safetensors"
    code, body, _ = call(server, "POST", "/infer", encode_request(observation()))
    assert code == 503
    assert body["error"] == "policy server is not ready: backend 'fake' failed to load: FileNotFoundError: checkpoint.safetensors"


def test_health_answers_while_an_inference_runs():
    gate = threading.Event()

    def slow(request):
        gate.wait(5)
        return chunk_answer(request)

    server = InferenceServer(FakeBackend(slow), ServerConfig(key=KEY)).start()
    try:
        assert server.ready.wait(5)
        worker = threading.Thread(target=call, args=(server, "POST", "/infer", encode_request(observation())))
        worker.start()
        code, health, _ = call(server, "GET", "/health", key=None)  # the inference waits on the gate meanwhile
        assert (code, health["status"]) == (200, "ready")
        gate.set()
        worker.join(5)
    finally:
        gate.set()
        server.stop()


def test_health_answers_while_many_large_requests_decode(serve, monkeypatch):
    """20 authenticated 5.8 MB requests at once: they are decoded one at a time (on main all at
    once, and /health waited for the GIL behind them: 2.2 s with 40), at most BODIES_AT_ONCE
    bodies are held, every request is answered, and every /health answers "ready" meanwhile."""
    import policy.server as server_module

    decoding, most = [0], [0]
    decode = server_module.decode_request

    def counted(body):
        decoding[0] += 1
        most[0] = max(most[0], decoding[0])
        try:
            return decode(body)
        finally:
            decoding[0] -= 1

    monkeypatch.setattr(server_module, "decode_request", counted)
    server = serve(FakeBackend(chunk_answer))
    big = encode_request(observation(images={"scene": np.random.default_rng(0).integers(0, 255, (1200, 1200, 3), dtype=np.uint8)}))
    codes: list[int] = []
    posts = [threading.Thread(target=lambda: codes.append(call(server, "POST", "/infer", big)[0])) for _ in range(20)]
    for thread in posts:
        thread.start()
    health: list[tuple[int, str]] = []
    while any(thread.is_alive() for thread in posts) and len(health) < 200:
        code, answer, _ = call(server, "GET", "/health", key=None)
        health.append((code, answer["status"]))
    for thread in posts:
        thread.join(30)
    assert codes == [200] * 20 and most[0] == 1
    assert health and all(code == 200 and status == "ready" for code, status in health)


def test_a_client_dripping_its_headers_is_cut_off_at_the_deadline(serve):
    """A byte every 0.2 s kept a connection open forever on main, before its key was read."""
    server = serve(FakeBackend(chunk_answer), header_deadline_s=1.0)
    started = time.monotonic()
    answer = b""
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as sock:
        sock.sendall(b"POST /infer HTTP/1.1\r\n")
        try:
            while time.monotonic() - started < 5.0 and not answer:
                sock.sendall(b"X")
                time.sleep(0.2)
                sock.setblocking(False)
                try:
                    answer = sock.recv(4096)
                except BlockingIOError:
                    pass
                finally:
                    sock.setblocking(True)
        except (BrokenPipeError, ConnectionResetError):
            pass
    assert answer.startswith(b"HTTP/1.1 408 "), answer
    assert b"the request line and headers did not arrive within 1 s" in answer  # before the client's 5 s


def test_an_idle_keep_alive_connection_outlives_the_header_deadline(serve):
    server = serve(FakeBackend(chunk_answer), header_deadline_s=0.5)
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
    try:
        for _ in range(2):
            conn.request("GET", "/health")
            response = conn.getresponse()
            assert response.status == 200 and json.loads(response.read())["status"] == "ready"
            time.sleep(1.0)  # idle longer than the deadline: it counts from a request's first byte
    finally:
        conn.close()


def test_warmup_images_option_is_parsed_with_clear_errors():
    assert parse_warmup_images("scene=224x224; wrist=480x640") == (("scene", 224, 224), ("wrist", 480, 640))
    with pytest.raises(ValueError, match="warmup image 'scene=224': expected name=HEIGHTxWIDTH"):
        parse_warmup_images("scene=224")


# --------------------------------------------------------------------------------------------
# Bearer key
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key, headers", [
    (None, {}),
    ("wrong-key", {}),
    (KEY[:-1], {}),
    (None, {"Authorization": f"Basic {KEY}"}),
    (None, {"Authorization": KEY}),
])
def test_infer_without_the_right_key_is_401_and_says_nothing_about_the_key(serve, key, headers):
    backend = FakeBackend(chunk_answer)
    server = serve(backend)
    code, body, response_headers = call(server, "POST", "/infer", encode_request(observation()), key=key, headers=headers)
    assert code == 401
    assert body == {"error": "unauthorized: send Authorization: Bearer <key>"}
    assert response_headers["WWW-Authenticate"] == "Bearer"
    assert backend.requests == []


def test_the_right_key_is_served(serve):
    backend = FakeBackend(chunk_answer)
    server = serve(backend)
    code, body, _ = call(server, "POST", "/infer", encode_request(observation()))
    assert code == 200
    answer = decode_response(json.dumps(body).encode())
    assert answer.status is PolicyStatus.CHUNK
    assert answer.actions.shape == (4, len(CELL_JOINTS))
    assert len(backend.requests) == 1


def test_server_refuses_to_start_without_a_key():
    with pytest.raises(ValueError, match=f"no bearer key: set {KEY_ENV} .* or pass --insecure-no-key"):
        ServerConfig(key=None)


def test_insecure_no_key_serves_anyone(serve):
    server = serve(FakeBackend(chunk_answer), key=None, insecure_no_key=True)
    code, _, _ = call(server, "POST", "/infer", encode_request(observation()), key=None)
    assert code == 200


# --------------------------------------------------------------------------------------------
# Bad requests, size limit, model errors
# --------------------------------------------------------------------------------------------
def _request_json(**changes) -> bytes:
    obj = json.loads(encode_request(observation()))
    obj.update(changes)
    return json.dumps(obj).encode()


@pytest.mark.parametrize("body, reason", [
    (b"{not json", "bad request: request body is not valid JSON"),
    (b"[1, 2]", "bad request: request body must be a JSON object"),
    (_request_json(version=2), "bad request: request 'version' must be 1, got 2"),
    (_request_json(temperature=0.5), "bad request: request has unknown fields: temperature"),
    (_request_json(joint_positions=encode_array(np.zeros(3))),
     "bad request: 'joint_positions' has shape [3], expected [7] (one per joint name)"),
    (_request_json(images=[{"dtype": "uint8", "shape": [8, 6, 3], "data": base64.b64encode(b"abc").decode()}]),
     "bad request: 'images[scene]' has 3 bytes of data, expected 144 for shape [8, 6, 3] of uint8"),
    (_request_json(images=[encode_array(np.zeros((8, 6), dtype=np.uint8))]),
     "bad request: 'images[scene]' must be a non-empty H x W x 3 RGB frame, got shape [8, 6]"),
    (_request_json(image_names=["scene", "wrist"]),
     "bad request: 'images' must be a list index-aligned with 'image_names': 1 images for 2 names"),
    (_request_json(frozen_prefix_steps=-1), "bad request: 'frozen_prefix_steps' must be an integer in [0, 2^32), got -1"),
    (_request_json(joint_positions=encode_array(np.array([np.nan] * 7))), "bad request: 'joint_positions' has non-finite values"),
    # absurd sizes and numbers: on main a 500 with a traceback
    (_request_json(joint_positions={"dtype": "float64", "shape": [0, 10**30], "data": ""}),
     "bad request: 'joint_positions' shape must be a list of at most 3 integers from 0 to 2147483647, got [0, 1000000000000000000000000000000]"),
    (_request_json(previous_action_chunk={"dtype": "float64", "shape": [0, 2**31 - 1, 2**31 - 1], "data": ""}),
     "bad request: 'previous_action_chunk' shape [0, 2147483647, 2147483647] is too large"),
    (_request_json(stamp=10**400), "bad request: 'stamp' must be a finite number of seconds >= 0, got 1000000000"),
    (_request_json(stamp=-1), "bad request: 'stamp' must be a finite number of seconds >= 0, got -1"),
])
def test_bad_request_shapes_are_400_with_the_reason(serve, body, reason):
    backend = FakeBackend(chunk_answer)
    server = serve(backend)
    code, answer, _ = call(server, "POST", "/infer", body)
    assert code == 400
    assert answer["error"].startswith(reason), answer["error"]
    assert backend.requests == []


def test_body_above_the_limit_is_413_before_it_is_read(serve):
    backend = FakeBackend(chunk_answer)
    server = serve(backend, max_body_bytes=4096)
    body = encode_request(observation(images={"scene": np.zeros((64, 64, 3), dtype=np.uint8)}))
    assert len(body) > 4096
    code, answer, _ = call(server, "POST", "/infer", body)
    assert code == 413
    assert answer["error"] == f"request body of {len(body)} bytes exceeds the limit of 4096 bytes"
    assert backend.requests == []


def test_missing_content_length_is_411(serve):
    server = serve(FakeBackend(chunk_answer))
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
    try:
        conn.putrequest("POST", "/infer")
        conn.putheader("Authorization", f"Bearer {KEY}")
        conn.endheaders()
        response = conn.getresponse()
        assert response.status == 411
        assert json.loads(response.read())["error"] == "a Content-Length header is required"
    finally:
        conn.close()


def test_backend_exception_is_500_with_its_message(serve):
    server = serve(FakeBackend(RuntimeError("CUDA out of memory")))
    code, body, _ = call(server, "POST", "/infer", encode_request(observation()))
    assert code == 500
    assert body["error"] == "policy backend 'fake' failed: RuntimeError: CUDA out of memory"


def test_backend_error_answer_is_a_200_error_status(serve):
    server = serve(FakeBackend(PolicyResponse.error("cannot read the prompt")))
    code, body, _ = call(server, "POST", "/infer", encode_request(observation()))
    assert code == 200
    assert (body["status"], body["message"], body["actions"]) == ("error", "cannot read the prompt", None)


def test_unknown_path_is_404(serve):
    server = serve(FakeBackend(chunk_answer))
    assert call(server, "GET", "/metrics", key=None)[0] == 404
    assert call(server, "POST", "/predict", b"{}")[0] == 404


def test_one_inference_at_a_time():
    active, most = [0], [0]
    lock = threading.Lock()

    def counting(request):
        with lock:
            active[0] += 1
            most[0] = max(most[0], active[0])
        time.sleep(0.05)
        with lock:
            active[0] -= 1
        return chunk_answer(request)

    server = InferenceServer(FakeBackend(counting), ServerConfig(key=KEY)).start()
    try:
        assert server.ready.wait(5)
        workers = [threading.Thread(target=call, args=(server, "POST", "/infer", encode_request(observation())))
                   for _ in range(4)]
        for w in workers:
            w.start()
        for w in workers:
            w.join(10)
        assert most[0] == 1
        assert server.requests == 4
    finally:
        server.stop()


def test_a_hung_backend_call_never_wedges_the_server(serve):
    """One call that never returns (released at the end): later requests are answered 503 busy
    after ``lock_wait_s``, then at once once the call is over ``infer_deadline_s``, when /health
    says the backend looks hung; no thread piles up; the server serves again once it returns."""
    gate = threading.Event()
    backend = FakeBackend(chunk_answer, infer_gate=gate)
    server = serve(backend, lock_wait_s=0.2, infer_deadline_s=1.0)
    try:
        hung = threading.Thread(target=call, args=(server, "POST", "/infer", encode_request(observation())))
        hung.start()
        deadline = time.monotonic() + 10
        while not backend.requests and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(backend.requests) == 1
        code, body, _ = call(server, "POST", "/infer", encode_request(observation()))
        assert code == 503 and body["error"].startswith("policy server is busy: it runs one inference at a time, ")
        assert body["error"].endswith(" and this request waited 0.2 s; try again")

        while call(server, "GET", "/health", key=None)[1]["status"] == "ready" and time.monotonic() < deadline:
            time.sleep(0.05)
        code, health, _ = call(server, "GET", "/health", key=None)
        assert (code, health["status"]) == (200, "error")
        assert health["message"].startswith("backend 'fake' has been in one inference for ")
        assert health["message"].endswith(" s, over its deadline of 1 s: it looks hung (restart the server)")
        threads = threading.active_count()
        answers = [call(server, "POST", "/infer", encode_request(observation())) for _ in range(20)]
        assert {(code, body["error"].split(":")[0]) for code, body, _ in answers} == {(503, "policy server is not ready")}
        assert threading.active_count() <= threads + 1  # each request's thread has ended
    finally:
        gate.set()
        hung.join(10)
    assert call(server, "GET", "/health", key=None)[1]["status"] == "ready"
    assert call(server, "POST", "/infer", encode_request(observation()))[0] == 200


# --------------------------------------------------------------------------------------------
# Wire format
# --------------------------------------------------------------------------------------------
def test_request_round_trip_is_exact_and_images_are_lossless():
    rng = np.random.default_rng(3)
    request = observation(
        images={"scene": rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), "wrist": rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)},
        previous_action_chunk=rng.normal(size=(20, 9)),
        previous_anchor_positions=rng.normal(size=7),
        frozen_prefix_steps=6,
        guidance_horizon=10,
        new_episode=False,
        stamp=123.456789,
    )
    decoded = decode_request(encode_request(request))
    assert list(decoded.images) == ["scene", "wrist"]
    for name in request.images:
        assert np.array_equal(decoded.images[name], request.images[name])
    assert np.array_equal(decoded.joint_positions, request.joint_positions)
    assert np.array_equal(decoded.previous_action_chunk, request.previous_action_chunk)
    assert np.array_equal(decoded.previous_anchor_positions, request.previous_anchor_positions)
    assert (decoded.prompt, decoded.joint_names, decoded.new_episode) == (request.prompt, request.joint_names, False)
    assert (decoded.frozen_prefix_steps, decoded.guidance_horizon, decoded.stamp) == (6, 10, 123.456789)


def test_response_round_trip_and_strictness():
    actions, policy = np.random.default_rng(1).normal(size=(50, 7)), np.random.default_rng(2).normal(size=(50, 32))
    decoded = decode_response(encode_response(PolicyResponse.chunk(actions, 0.1, policy, "ok")))
    assert decoded.status is PolicyStatus.CHUNK and decoded.message == "ok"
    assert np.array_equal(decoded.actions, actions) and np.array_equal(decoded.policy_actions, policy)
    assert decoded.native_control_period == 0.1
    assert decode_response(encode_response(PolicyResponse.no_more_actions("end"))).status is PolicyStatus.NO_MORE_ACTIONS
    with pytest.raises(WireError, match="'actions' is null in a chunk answer"):
        decode_response(json.dumps({"version": 1, "status": "chunk", "message": "", "actions": None,
                                    "native_control_period": 0.1, "policy_actions": None}).encode())
    with pytest.raises(WireError, match="'status' must be one of chunk, no_more_actions, error, got 'done'"):
        decode_response(json.dumps({"version": 1, "status": "done", "message": "", "actions": None,
                                    "native_control_period": 0.0, "policy_actions": None}).encode())


def test_nothing_on_the_wire_is_pickle():
    import re

    for name in ("policy/wire.py", "policy/server.py", "policy/http_client.py", "policy/node.py", "sim/oracle_remote.py"):
        source = (ROOT / name).read_text()
        assert not re.search(r"import\s+(c?pickle|dill|marshal)|(pickle|marshal)\.loads?\(|allow_pickle\s*=\s*True", source), name


@pytest.mark.parametrize("frozen, guidance, default, expected", [(5, 0, 10, 15), (5, 3, 10, 8), (0, 0, 10, 10), (7, 20, 0, 27)])
def test_guidance_horizon_converts_to_execution_horizon(frozen, guidance, default, expected):
    assert execution_horizon(frozen, guidance, default) == expected


# --------------------------------------------------------------------------------------------
# Malformed requests over raw sockets: every one gets a 4xx, and nothing unauthenticated is read
# --------------------------------------------------------------------------------------------
def raw(server: InferenceServer, data: bytes, timeout_s: float = 5.0) -> tuple[int, str]:
    """Send ``data`` as is; (status code, error reason or "") of the answer, (0, "") when none came."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=timeout_s) as sock:
        sock.sendall(data)
        sock.shutdown(socket.SHUT_WR)  # all of it is sent: a body shorter than declared ends here
        answer = b""
        try:
            while b"\r\n\r\n" not in answer or len(answer.partition(b"\r\n\r\n")[2]) < _declared(answer):
                piece = sock.recv(65536)
                if not piece:
                    break
                answer += piece
        except (ConnectionResetError, socket.timeout):
            pass
    if not answer.startswith(b"HTTP/1."):
        return 0, ""
    head, _, body = answer.partition(b"\r\n\r\n")
    code = int(head.split()[1])
    try:
        return code, json.loads(body).get("error", "")
    except ValueError:
        return code, ""


def _declared(answer: bytes) -> int:
    for line in answer.partition(b"\r\n\r\n")[0].split(b"\r\n"):
        if line.lower().startswith(b"content-length:"):
            return int(line.split(b":", 1)[1])
    return 0


def post(headers: list[bytes], body: bytes = b"", key: str | None = KEY) -> bytes:
    auth = [f"Authorization: Bearer {key}".encode()] if key else []
    return b"\r\n".join([b"POST /infer HTTP/1.1", b"Host: 127.0.0.1", *auth, *headers]) + b"\r\n\r\n" + body


NESTED = b"[" * 200_000 + b"]" * 200_000


@pytest.mark.parametrize("request_bytes, code, reason", [
    (post([b"Content-Length: \xb2"]), 400, "Content-Length must be a number of bytes, got '\xb2'"),
    (post([b"Content-Length: \xd9\xa3"]), 400, "Content-Length must be a number of bytes, got '\xd9\xa3'"),
    (post([b"Content-Length: -5"]), 400, "Content-Length must be a number of bytes, got '-5'"),
    (post([b"Content-Length: 1e3"]), 400, "Content-Length must be a number of bytes, got '1e3'"),
    (post([b"Content-Length: 99999999999999999999999"]), 400,
     "Content-Length must be a number of bytes, got '99999999999999999999999'"),
    (post([b"Content-Length: 4", b"Content-Length: 5"], b"null"), 400,
     "Content-Length is given 2 times with different values"),
    (post([b"Transfer-Encoding: chunked"], b"4\r\nnull\r\n0\r\n\r\n"), 411, "a Content-Length header is required"),
    (post([f"Content-Length: {len(NESTED)}".encode()], NESTED), 400,
     "bad request: request body nests JSON arrays or objects too deeply"),
    (post([b"Content-Length: \xb2"], key=None), 401, "unauthorized: send Authorization: Bearer <key>"),
    (post([f"Content-Length: {len(NESTED)}".encode()], NESTED, key="wrong"), 401,
     "unauthorized: send Authorization: Bearer <key>"),
    (b"GARBAGE\r\n\r\n", 400, ""),
    (b"POST /infer HTTP/1.1\r\nContent-Length 12\r\n\r\n", 401, "unauthorized: send Authorization: Bearer <key>"),
], ids=["superscript-two", "arabic-digit", "negative", "float", "huge", "two-lengths", "chunked", "nested-json",
        "bad-length-no-key", "nested-json-wrong-key", "garbage-line", "header-without-colon"])
def test_every_malformed_request_gets_a_4xx_with_the_reason(serve, request_bytes, code, reason):
    backend = FakeBackend(chunk_answer)
    server = serve(backend)
    assert raw(server, request_bytes) == (code, reason)
    assert backend.requests == []
    assert call(server, "GET", "/health")[0] == 200  # the server is still up


def test_nothing_past_the_headers_is_read_before_the_key_matches(serve):
    """An unauthenticated request declaring a large body that never comes is answered at once."""
    server = serve(FakeBackend(chunk_answer))
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as sock:
        sock.sendall(post([b"Content-Length: 1000000"], key=None))
        answer = sock.recv(4096)
    assert answer.startswith(b"HTTP/1.1 401 ")  # a server waiting for the body would time the recv out


def test_seeded_fuzz_of_headers_and_bodies_never_goes_unanswered(serve):
    """300 requests mixing random header values and bodies (seeded, bounded): each gets a 4xx,
    unless it happens to be a valid request."""
    backend = FakeBackend(chunk_answer)
    server = serve(backend, max_body_bytes=4096)
    rng = random.Random(7)
    valid = encode_request(observation())
    alphabet = [b"0", b"7", b"-", b" ", b"\xb2", b"\xbd", b"x", b"\t", b"+", b"e", b"\xff", b"9" * 30]
    for case in range(300):
        length = b"".join(rng.choice(alphabet) for _ in range(rng.randint(0, 4)))
        body = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 64)))
        if case % 3 == 0:  # a valid request with one byte flipped
            index = rng.randrange(len(valid))
            body = valid[:index] + bytes([valid[index] ^ 0x20]) + valid[index + 1:]
        exact, key = case % 5 == 0, KEY if case % 7 else "nope"
        headers = [f"Content-Length: {len(body)}".encode()] if exact else [b"Content-Length: " + length]
        code, _ = raw(server, post(headers, body, key=key), timeout_s=3.0)
        if code == 200:  # a flipped letter inside the prompt still makes a valid request
            assert exact and key == KEY and decode_request(body), (case, body[:40])
        else:
            assert 400 <= code < 500, (case, length, body[:40], code)
    assert call(server, "GET", "/health")[0] == 200


# --------------------------------------------------------------------------------------------
# Keyless servers stay on loopback; every warning is true of the configuration
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.168.1.20", "robot-pc.local"])
def test_a_keyless_server_is_refused_off_loopback(host):
    with pytest.raises(ValueError, match=f"refusing to serve /infer without a bearer key on {host}, which is not a "
                                         "loopback address"):
        ServerConfig(host=host, key=None, insecure_no_key=True)


@pytest.mark.parametrize("config, warnings", [
    (ServerConfig(key=KEY), []),
    (ServerConfig(host="::1", key=KEY), []),
    (ServerConfig(host="127.0.0.2", key=None, insecure_no_key=True),
     ["serving /infer without a bearer key (--insecure-no-key): any process on this machine can call the policy"]),
    (ServerConfig(host="0.0.0.0", key=KEY),
     ["serving plain HTTP on 0.0.0.0: the bearer key and every observation travel in cleartext; "
      "use TLS (--tls-cert/--tls-key) or a private network"]),
    (ServerConfig(host="0.0.0.0", key=KEY, tls_cert=Path("c.pem"), tls_key=Path("k.pem")), []),
    (ServerConfig(host="0.0.0.0", key=None, insecure_no_key=True, tls_cert=Path("c.pem"), tls_key=Path("k.pem"),
                  tls_client_ca=Path("ca.pem")),
     ["serving /infer without a bearer key (--insecure-no-key): any client with a certificate from "
      "--tls-client-ca can call the policy"]),
])
def test_start_warnings_match_the_configuration(config, warnings):
    assert exposure_warnings(config) == warnings


@pytest.mark.parametrize("port", ["70000", "-1", "３０", "1_000"])
def test_serve_refuses_a_port_that_is_not_one_with_a_usage_error(capsys, port):
    """On main 70000 and -1 reached the socket and printed an unexpected OverflowError."""
    from runtime.app.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["serve", "--backend", "replay", f"--port={port}"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.endswith(f"objective serve: error: argument --port: expected a TCP port number (0-65535), got '{port}'\n")


def test_serve_refuses_a_keyless_server_on_all_interfaces(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != KEY_ENV}
    replay = tmp_path / "r.jsonl"
    write_replay(replay, [RecordedChunk(list(CELL_JOINTS), np.zeros((3, 7)), 0.1)])
    proc = _objective("serve", "--backend", "replay", "--replay-file", str(replay), "--insecure-no-key",
                      "--host", "0.0.0.0", env=env)
    try:
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 2
    assert "error: refusing to serve /infer without a bearer key on 0.0.0.0" in err
    assert "listening" not in out and "cleartext" not in err


# --------------------------------------------------------------------------------------------
# `objective serve` as a process
# --------------------------------------------------------------------------------------------
def _objective(*args: str, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "runtime.app.cli", *args], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_serve_refuses_to_start_without_a_key(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != KEY_ENV}
    replay = tmp_path / "r.jsonl"
    write_replay(replay, [RecordedChunk(list(CELL_JOINTS), np.zeros((3, 7)), 0.1)])
    proc = _objective("serve", "--backend", "replay", "--replay-file", str(replay), env=env)
    try:
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 2
    assert f"error: no bearer key: set {KEY_ENV}" in err
    assert "listening" not in out


def test_serve_process_reports_its_port_serves_and_stops_on_sigterm(tmp_path):
    replay = tmp_path / "r.jsonl"
    write_replay(replay, [RecordedChunk(list(CELL_JOINTS), np.full((3, 7), 0.2), 0.1)])
    proc = _objective("serve", "--backend", "replay", "--replay-file", str(replay), "--port", "0",
                      env={**os.environ, KEY_ENV: KEY})
    try:
        line = proc.stdout.readline()
        assert line.startswith("listening on http://127.0.0.1:"), line
        port = int(line.rsplit(":", 1)[1])
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
        deadline = time.monotonic() + 10
        while True:
            conn.request("GET", "/health")
            health = json.loads(conn.getresponse().read())
            if health["status"] != "loading" or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        assert health["status"] == "ready"
        conn.request("POST", "/infer", body=encode_request(observation()), headers={"Authorization": f"Bearer {KEY}"})
        response = conn.getresponse()
        answer = decode_response(response.read())
        conn.close()
        assert response.status == 200 and np.allclose(answer.actions, 0.2)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        err = proc.stderr.read()
        assert "POST /infer 200" in err
        assert "stopped after 1 inference requests" in err
    finally:
        proc.kill()
        proc.wait()


# --------------------------------------------------------------------------------------------
# The oracle backend in its own process: cube poses over ROS 2, time from the request stamp
# --------------------------------------------------------------------------------------------
@pytest.mark.ros
def test_remote_oracle_answers_what_the_embedded_oracle_answers():
    from runtime.io.clock import WallClock
    from runtime.io.ros import RosBus
    from geometry_msgs.msg import TransformStamped
    from sim.layouts import layout
    from sim.planning import CUBE_SIZE
    from sim.oracle import OracleBackend, SceneKinematics
    from sim.oracle_remote import CUBE_POSE_TOPIC, RemoteOracleBackend, cube_pose_msg
    from sim.robot_model import ARM_JOINTS, load_waypoints, planning_robot_model

    cubes = {c: (np.array([x, y, CUBE_SIZE / 2]), np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]))
             for c, (x, y, yaw) in layout(0).items()}
    ready = load_waypoints()["Ready"]
    request = observation(joint_positions=np.array([ready[j] for j in ARM_JOINTS] + [0.0]), stamp=3.25)
    robot = planning_robot_model()

    class Peek:
        kinematics = SceneKinematics(robot)

        def cube_pose(self, color):
            return cubes[color]

        def time(self):
            return 3.25

    expected = OracleBackend(Peek()).infer(request)
    world = RosBus(WallClock(), node_name="fake_world")
    remote = RemoteOracleBackend(robot=robot, wait_s=5.0)
    try:
        for color, (pos, quat) in cubes.items():
            world.create_lazy_publisher(CUBE_POSE_TOPIC.format(color=color), TransformStamped,
                                        lambda c=color: cube_pose_msg(c, *cubes[c], 3.0), rate_hz=50.0)
        remote.load()
        answer = remote.infer(request)
    finally:
        remote.close()
        world.close()
    assert answer.status is PolicyStatus.CHUNK, answer.message
    assert answer.actions.shape == (50, 7)
    assert np.allclose(answer.actions, expected.actions, atol=1e-9)


@pytest.mark.ros
def test_remote_oracle_without_cube_poses_answers_error_naming_the_topics():
    from sim.oracle_remote import RemoteOracleBackend
    from sim.robot_model import planning_robot_model

    remote = RemoteOracleBackend(robot=planning_robot_model(), wait_s=0.2, node_name="lonely_oracle")
    try:
        remote.load()
        answer = remote.infer(observation())
    finally:
        remote.close()
    assert answer.status is PolicyStatus.ERROR
    assert answer.message.startswith(
        "the oracle has no cube pose on /cube_poses/cube_red, /cube_poses/cube_green, /cube_poses/cube_blue after 0.2 s"
    )


def test_kinematic_world_publishes_cube_poses_for_the_remote_oracle():
    from runtime.tree.behavior import RunContext
    from runtime.io.bus import InProcessBus
    from runtime.io.clock import SimClock
    from runtime.tree.events import EventLog
    from geometry_msgs.msg import TransformStamped
    from sim.kinematic import KinematicWorld
    from sim.oracle_remote import pose_from_msg

    clock = SimClock()
    bus = InProcessBus(clock)
    context = RunContext(clock=clock, bus=bus, events=EventLog(clock))
    world = KinematicWorld({"policy": "none"})
    world.start(context)
    world.step_to(0.5)
    sub = bus.create_subscription("/cube_poses/cube_red", TransformStamped)
    msg = sub.latest
    assert (msg.header.frame_id, msg.child_frame_id) == ("world", "cube_red")
    assert msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 == pytest.approx(0.5)
    position, quat = pose_from_msg(msg)
    expected_position, expected_quat = world.cell.cube_pose("red")
    assert np.allclose(position, expected_position) and np.allclose(quat, expected_quat)
