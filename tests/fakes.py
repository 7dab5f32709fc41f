"""A policy backend scripted by a test, shared by the adapter, server and smoke-test tests."""
from __future__ import annotations

import threading
from typing import Any

from policy.backend import PolicyRequest


class FakeBackend:
    """Keeps every warmup and request, and answers ``answer``: a response, an exception to
    raise, or a function of the request.

    ``gated``: ``load`` waits until the test sets ``release``. ``infer_gate``: every ``infer``
    waits for it (a slow model). ``load_error`` is raised by ``load``.
    """

    def __init__(self, answer: Any = None, gated: bool = False, load_error: Exception | None = None,
                 infer_gate: threading.Event | None = None, name: str = "fake") -> None:
        self.name = name
        self.answer = answer
        self.release = threading.Event()
        if not gated:
            self.release.set()
        self.load_error = load_error
        self.infer_gate = infer_gate
        self.warmups: list[PolicyRequest] = []
        self.requests: list[PolicyRequest] = []

    def load(self) -> None:
        assert self.release.wait(10), "test never released the load"
        if self.load_error:
            raise self.load_error

    def warmup(self, example_request: PolicyRequest) -> None:
        self.warmups.append(example_request)

    def infer(self, request: PolicyRequest) -> Any:
        self.requests.append(request)
        if self.infer_gate is not None:
            self.infer_gate.wait(10)
        if isinstance(self.answer, Exception):
            raise self.answer
        if callable(self.answer):
            return self.answer(request)
        return self.answer


SLOW_INFER_S = 0.5
"""How long ``slow_hold``'s every answer takes, in wall time."""


def slow_hold(options: Any = None) -> FakeBackend:
    """A backend factory (``tests.fakes:slow_hold``): a slow model (``SLOW_INFER_S`` of wall time
    per answer) whose chunks hold the observed state, 30 steps of 0.1 s."""
    import time

    import numpy as np

    from policy.backend import PolicyResponse

    def hold(request: PolicyRequest) -> PolicyResponse:
        time.sleep(SLOW_INFER_S)
        return PolicyResponse.chunk(np.tile(np.asarray(request.joint_positions, dtype=float), (30, 1)), 0.1, None)

    return FakeBackend(hold, name="slow hold")
