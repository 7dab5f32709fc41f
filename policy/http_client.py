"""``HttpBackend``: a ``PolicyBackend`` that forwards each request to the HTTP inference server.

The adapter node wraps it in a ``PolicyAdapter``, which converts the GetActionChunk messages and
validates the chunk; this module owns the transport and its failure modes. Every failure becomes
an ERROR answer with a reason, within the timeout, never NO_MORE_ACTIONS and never a hang:

- unreachable server (refused, reset, DNS, TLS verification): "cannot reach the inference server at URL: ..."
- no complete answer within ``timeout`` seconds (one deadline for connect, send and receive):
  "the inference server at URL did not answer within T s"
- ``4xx``/``5xx``: "the inference server at URL answered 503: <the server's reason>"
- a ``200`` body that is not a valid answer: "the inference server at URL sent a malformed answer: ..."

Where the server may be (``check_infer_url``, enforced when the backend is built, so a bad URL
stops the adapter at start-up with the reason):

- ``http://`` only to a loopback host (``127.0.0.0/8``, ``::1``, ``localhost``): the bearer key
  and the camera frames travel in cleartext, which is acceptable on one machine only;
- ``https://`` to any host, always with certificate verification
  (``ssl.create_default_context``: chain and hostname), optionally against ``ca_file`` and
  with a client certificate. Turning verification off is not offered.

A new connection per request keeps the backend stateless and safe to call from several
executor threads; on loopback the connection costs well under a millisecond.
"""
from __future__ import annotations

import http.client
import ipaddress
import json
import logging
import re
import ssl
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from runtime.errors import ObjectiveError, OptionError

from .backend import PolicyRequest, PolicyResponse
from .wire import CONTENT_TYPE, WireError, decode_response, encode_request, read_error

DEFAULT_TIMEOUT_S = 2.5
"""Below ExecutePolicy's default ``policy_call_timeout`` (3 s), so the caller gets our reason
rather than its own timeout."""
MAX_RESPONSE_BYTES = 64 * 1024 * 1024
_SEND_PIECE = 1 << 20

log = logging.getLogger("policy.http_client")


class InferUrlError(ObjectiveError, ValueError):
    """An ``infer_url`` the adapter refuses to use; the message says why and what to do."""


@dataclass(frozen=True)
class Endpoint:
    """A checked ``infer_url``."""

    scheme: str
    host: str
    port: int
    infer_path: str
    health_path: str

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}{self.infer_path}"

    @property
    def health_url(self) -> str:
        return self.url[: -len(self.infer_path)] + self.health_path


def is_loopback(host: str) -> bool:
    """``localhost``, an address in 127.0.0.0/8, or ``::1`` (brackets and spaces ignored)."""
    host = host.strip().strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: it may resolve to anything


def redact_url(url: str) -> str:
    """``url`` fit to print: user name and password (everything before the last ``@``), query and
    fragment replaced by ``***``, so an error message or log line never repeats a secret."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        scheme, rest = "", url
    rest = re.sub(r"[?#].*", "?***", rest, flags=re.DOTALL)
    if "@" in rest:
        rest = "***@" + rest.rpartition("@")[2]
    return f"{scheme}{sep}{rest}"


def check_infer_url(url: str, tls_files: bool = False) -> Endpoint:
    """Parse ``url`` and apply the policy above; ``InferUrlError`` with the reason.

    ``url`` may be the server's base (``http://127.0.0.1:8000``, ``/infer`` is appended) or the
    full endpoint. ``tls_files`` says a CA file or client certificate was given, which only
    makes sense with ``https://``.
    """
    try:
        parts = urlsplit(url.strip())
        port = parts.port
    except ValueError as exc:
        raise InferUrlError(f"infer_url {redact_url(url)!r} is not a valid URL ({exc})") from None
    shown = redact_url(url)
    scheme = parts.scheme.lower()
    if scheme not in ("http", "https"):
        raise InferUrlError(f"infer_url {shown!r} must start with http:// (loopback only) or https://")
    host = parts.hostname or ""
    if not host:
        raise InferUrlError(f"infer_url {shown!r} has no host")
    if parts.username or parts.password:
        raise InferUrlError(f"infer_url {shown!r} must not carry credentials: the key comes from POLICY_SERVER_KEY")
    if parts.query or parts.fragment:
        raise InferUrlError(f"infer_url {shown!r} must not have a query or fragment")
    if scheme == "http" and not is_loopback(host):
        raise InferUrlError(
            f"refusing plain http to {host}, which is not a loopback address: the bearer key and the camera "
            "frames would cross the network in cleartext. Serve the model on this machine (127.0.0.1), or "
            "use https:// (the certificate is verified; --ca-file for a private CA)"
        )
    if scheme == "http" and tls_files:
        raise InferUrlError("a CA file or client certificate was given for a plain http:// infer_url; they need https://")
    path = parts.path.rstrip("/")
    infer_path = path if path else "/infer"
    base = infer_path[: -len("/infer")] if infer_path.endswith("/infer") else infer_path
    return Endpoint(scheme, host, port or (443 if scheme == "https" else 80), infer_path, base + "/health")


@dataclass(frozen=True)
class ClientConfig:
    infer_url: str
    timeout: float = DEFAULT_TIMEOUT_S
    """One deadline for the whole exchange (connect, send, wait, receive), seconds."""
    key: str | None = None
    """Sent as ``Authorization: Bearer <key>`` (from ``POLICY_SERVER_KEY``)."""
    ca_file: Path | None = None
    client_cert: Path | None = None
    client_key: Path | None = None

    def __post_init__(self) -> None:
        if not self.timeout > 0:
            raise OptionError(f"timeout must be positive, got {self.timeout}")
        if self.client_key is not None and self.client_cert is None:
            raise OptionError("a client key needs its client certificate (--client-cert)")


class HttpBackend:
    """Forwards ``PolicyRequest``s to an inference server (see the module docstring).

    The URL is checked and the TLS context built in ``__init__``, so a misconfigured adapter
    fails at start-up; ``load``/``warmup`` do nothing (the server loads and warms up itself).
    """

    name = "http"

    def __init__(self, config: ClientConfig) -> None:
        self.config = config
        self.endpoint = check_infer_url(
            config.infer_url, tls_files=any(f is not None for f in (config.ca_file, config.client_cert))
        )
        self.url = self.endpoint.url
        self._tls: ssl.SSLContext | None = None
        if self.endpoint.scheme == "https":
            for label, path in (("CA file", config.ca_file), ("client certificate", config.client_cert),
                                ("client key", config.client_key)):
                if path is not None and not Path(path).is_file():
                    raise InferUrlError(f"{label} {path}: no such file")
            self._tls = ssl.create_default_context(cafile=str(config.ca_file) if config.ca_file else None)
            if config.client_cert is not None:
                self._tls.load_cert_chain(str(config.client_cert), str(config.client_key) if config.client_key else None)

    def load(self) -> None:
        """Nothing: the server loads its model and reports through ``health()``."""

    def warmup(self, example_request: PolicyRequest) -> None:
        """Nothing: the server runs its own full-size warmup before it reports ready."""

    # -- calls ---
    def infer(self, request: PolicyRequest) -> PolicyResponse:
        started = time.monotonic()
        try:
            code, payload = self._exchange("POST", self.endpoint.infer_path, encode_request(request))
        except TimeoutError:
            return PolicyResponse.error(
                f"the inference server at {self.url} did not answer within {self.config.timeout:g} s"
            )
        except _Unreachable as exc:
            return PolicyResponse.error(f"cannot reach the inference server at {self.url}: {exc}")
        if code != 200:
            return PolicyResponse.error(f"the inference server at {self.url} answered {code}: {read_error(payload)}")
        try:
            response = decode_response(payload)
        except WireError as exc:
            return PolicyResponse.error(f"the inference server at {self.url} sent a malformed answer: {exc}")
        log.debug("%s answered %s in %.1f ms", self.url, response.status.value, (time.monotonic() - started) * 1000)
        return response

    def health(self) -> dict[str, Any]:
        """``GET /health`` as a dict; ``{"status": "unreachable", "message": ...}`` on any failure."""
        try:
            code, payload = self._exchange("GET", self.endpoint.health_path, None)
            if code != 200:
                return {"status": "unreachable", "message": f"answered {code}: {read_error(payload)}"}
            data = json.loads(payload)
            if not isinstance(data, dict) or not isinstance(data.get("status"), str):
                return {"status": "unreachable", "message": "health answer is not a JSON object with a status"}
            return data
        except TimeoutError:
            return {"status": "unreachable", "message": f"no answer within {self.config.timeout:g} s"}
        except _Unreachable as exc:
            return {"status": "unreachable", "message": str(exc)}
        except ValueError:
            return {"status": "unreachable", "message": "health answer is not JSON"}

    # -- transport ---
    def _exchange(self, method: str, path: str, body: bytes | None) -> tuple[int, bytes]:
        """One request on a fresh connection within one deadline: ``(status, body)``.

        Raises ``TimeoutError`` past the deadline and ``_Unreachable`` for every other
        transport failure.
        """
        deadline = time.monotonic() + self.config.timeout

        def remaining() -> float:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError
            return left

        host, port = self.endpoint.host, self.endpoint.port
        if self._tls is not None:
            conn: http.client.HTTPConnection = http.client.HTTPSConnection(host, port, timeout=remaining(), context=self._tls)
        else:
            conn = http.client.HTTPConnection(host, port, timeout=remaining())
        send_error: OSError | None = None
        try:
            conn.putrequest(method, path, skip_accept_encoding=True)
            conn.putheader("Accept", CONTENT_TYPE)
            if self.config.key:
                conn.putheader("Authorization", f"Bearer {self.config.key}")
            if body is not None:
                conn.putheader("Content-Type", CONTENT_TYPE)
                conn.putheader("Content-Length", str(len(body)))
            conn.endheaders()  # connects (and handshakes) here
            sock = conn.sock  # kept: the connection lets go of it once a response says "close"
            view = memoryview(body or b"")
            try:
                for start in range(0, len(view), _SEND_PIECE):
                    sock.settimeout(remaining())
                    sock.sendall(view[start : start + _SEND_PIECE])
            except (BrokenPipeError, ConnectionResetError) as exc:
                send_error = exc  # the server may have answered early (401, 413): read that answer
            sock.settimeout(remaining())
            response = conn.getresponse()
            chunks, size = [], 0
            while True:
                sock.settimeout(remaining())
                piece = response.read1(1 << 16)
                if not piece:
                    break
                size += len(piece)
                if size > MAX_RESPONSE_BYTES:
                    raise _Unreachable(f"the answer exceeds {MAX_RESPONSE_BYTES} bytes")
                chunks.append(piece)
            return response.status, b"".join(chunks)
        except TimeoutError:
            raise
        except ssl.SSLCertVerificationError as exc:
            raise _Unreachable(f"TLS certificate verification failed ({exc.verify_message})") from None
        except (OSError, http.client.HTTPException) as exc:
            if send_error is not None:
                raise _Unreachable(
                    f"the server closed the connection while receiving the {len(body or b'')}-byte request "
                    f"({type(send_error).__name__}); a request above its size limit is refused this way"
                ) from None
            raise _Unreachable(_describe(exc)) from None
        finally:
            conn.close()


class _Unreachable(Exception):
    """A transport failure other than the deadline; the message is the reason."""


def _describe(exc: BaseException) -> str:
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused (is the server running, on this port?)"
    if isinstance(exc, http.client.RemoteDisconnected):
        return "the server closed the connection without answering"
    if isinstance(exc, ssl.SSLError):
        return f"TLS error ({exc.reason or exc})"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
