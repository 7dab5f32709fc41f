"""The GetActionChunk adapter: serves ``moveit_pro_ml_msgs/srv/GetActionChunk`` from a ``PolicyBackend``.

This is the adapter the guide describes, minus the transport: ``PolicyAdapter.handle`` takes a
request message and returns a response message, so the same code answers on the in-process bus
(``serve(bus)``, headless runs), inside an rclpy node, or in front of an HTTP client backend.

What it guarantees to the caller (ExecutePolicy), whatever the backend does:

- ``chunk.joint_names`` echoes ``robot_state.name``, which satisfies both of the contract's
  naming rules (by order without a gripper, by name with one).
- A CHUNK_PRODUCED answer has at least one point, one column per observed joint, finite values.
- Any failure (a bad request, a backend exception, ``sys.exit`` or ``KeyboardInterrupt`` in the
  backend's code, an answer that breaks the rules above) is
  answered with ERROR and a reason. Never NO_MORE_ACTIONS, never an exception, never silence:
  an error reported as a graceful end would let the Objective act on a rollout that never ran.
- It counts served chunks (``served_chunks``) and logs the count every ``log_every`` chunks, the
  counter the guide's bring-up says to watch climbing during a run.

The conversion functions (``request_from_msg``, ``request_to_msg``, ``response_to_msg``,
``response_from_msg``, ``validate_response``, ``array_to_multiarray``, ``multiarray_to_array``)
are public for the ROS 2 node, the HTTP server and bring-up tools.
"""
from __future__ import annotations

import logging
import math
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectoryPoint

from runtime.io.timestamps import duration_msg, time_msg, to_seconds
from runtime.errors import ObjectiveError, OptionError
from runtime.io.interrupt import describe_error, raised_by_code

from .backend import PolicyBackend, PolicyRequest, PolicyResponse, PolicyStatus
from .images import image_to_rgb, rgb_to_image

DEFAULT_SERVICE_NAME = "/get_action_chunk"

_STATUS_TO_MSG = {
    PolicyStatus.CHUNK: GetActionChunk.Response.CHUNK_PRODUCED,
    PolicyStatus.NO_MORE_ACTIONS: GetActionChunk.Response.NO_MORE_ACTIONS,
    PolicyStatus.ERROR: GetActionChunk.Response.ERROR,
}


class RequestError(ObjectiveError, ValueError):
    """The request message cannot be turned into a ``PolicyRequest``; says which field and why."""


class ResponseError(ObjectiveError, ValueError):
    """The backend's answer breaks the contract; says how."""


# --------------------------------------------------------------------------------------------
# Float64MultiArray <-> (steps, dims) arrays, step dimension first, data_offset 0
# --------------------------------------------------------------------------------------------
def array_to_multiarray(array: NDArray[np.float64] | None) -> Float64MultiArray:
    """A (steps, dims) array as ``Float64MultiArray`` with dims ``steps``, ``actions``; None -> empty."""
    msg = Float64MultiArray()
    if array is None:
        return msg
    data = np.asarray(array, dtype=float)
    if data.ndim != 2:
        raise ValueError(f"action arrays must be 2-D (steps, dims), got shape {data.shape}")
    steps, width = data.shape
    msg.layout.dim = [
        MultiArrayDimension(label="steps", size=steps, stride=steps * width),
        MultiArrayDimension(label="actions", size=width, stride=width),
    ]
    msg.layout.data_offset = 0
    msg.data = np.ascontiguousarray(data).ravel()
    return msg


def multiarray_to_array(msg: Float64MultiArray, field: str = "array") -> NDArray[np.float64] | None:
    """A ``Float64MultiArray`` (step dimension first) as (steps, dims), or None when empty.

    A non-zero ``data_offset`` reads as empty, as the contract says. Data whose size does not
    match its layout raises ``ValueError`` naming ``field``.
    """
    data = np.asarray(msg.data, dtype=float)
    if data.size == 0 or msg.layout.data_offset != 0:
        return None
    dims = list(msg.layout.dim)
    if not dims:
        raise ValueError(f"{field} has {data.size} values but no layout.dim (expected steps first, then action dims)")
    steps = int(dims[0].size)
    if steps <= 0 or data.size % steps != 0:
        raise ValueError(f"{field} has {data.size} values, which is not a whole number of rows for {steps} steps")
    width = data.size // steps
    if len(dims) >= 2 and int(np.prod([d.size for d in dims[1:]])) != width:
        sizes = " x ".join(str(d.size) for d in dims)
        raise ValueError(f"{field} has {data.size} values for layout {sizes}")
    return data.reshape(steps, width)


# --------------------------------------------------------------------------------------------
# Request conversion
# --------------------------------------------------------------------------------------------
def request_from_msg(msg: GetActionChunk.Request) -> PolicyRequest:
    """Convert a GetActionChunk request; raises ``RequestError`` naming the bad field."""
    names = [str(n) for n in msg.robot_state.name]
    positions = np.asarray(msg.robot_state.position, dtype=float)
    if not names:
        raise RequestError("robot_state.name is empty: it must list the group joints, then the gripper joint")
    if len(set(names)) != len(names):
        raise RequestError(f"robot_state.name lists a joint twice: [{', '.join(names)}]")
    if positions.shape != (len(names),):
        raise RequestError(f"robot_state has {len(names)} names but {positions.size} positions")
    if not np.all(np.isfinite(positions)):
        bad = names[int(np.argmin(np.isfinite(positions)))]
        raise RequestError(f"robot_state position of '{bad}' is not finite")
    image_names = [str(n) for n in msg.image_names]
    if len(image_names) != len(msg.images):
        raise RequestError(f"{len(msg.images)} images but {len(image_names)} image_names (they must be index-aligned)")
    if len(set(image_names)) != len(image_names):
        raise RequestError(f"image_names lists a name twice: [{', '.join(image_names)}]")
    try:
        images = {name: image_to_rgb(image, name) for name, image in zip(image_names, msg.images)}
        previous = multiarray_to_array(msg.previous_action_chunk, "previous_action_chunk")
    except ValueError as exc:
        raise RequestError(str(exc)) from None
    return PolicyRequest(
        prompt=str(msg.prompt),
        joint_names=names,
        joint_positions=positions,
        images=images,
        new_episode=bool(msg.new_episode),
        previous_action_chunk=previous,
        previous_anchor_positions=_anchor_positions(msg.previous_anchor_state, names),
        frozen_prefix_steps=int(msg.frozen_prefix_steps),
        guidance_horizon=int(msg.guidance_horizon),
        stamp=to_seconds(msg.robot_state.header.stamp),
    )


def _anchor_positions(anchor: JointState, names: Sequence[str]) -> NDArray[np.float64] | None:
    """The anchor's positions in request order (by name when it names its joints)."""
    positions = np.asarray(anchor.position, dtype=float)
    if positions.size == 0:
        return None
    anchor_names = list(anchor.name)
    if not anchor_names:
        if positions.size != len(names):
            raise RequestError(f"previous_anchor_state has {positions.size} positions for {len(names)} joints")
        return positions
    if len(anchor_names) != positions.size:
        raise RequestError(f"previous_anchor_state has {len(anchor_names)} names but {positions.size} positions")
    missing = [n for n in names if n not in anchor_names]
    if missing:
        raise RequestError(f"previous_anchor_state lacks [{', '.join(missing)}] (it names [{', '.join(anchor_names)}])")
    return positions[[anchor_names.index(n) for n in names]]


def request_to_msg(request: PolicyRequest, image_encoding: str = "rgb8") -> GetActionChunk.Request:
    """Build a GetActionChunk request (smoke tests, bring-up tools, tests)."""
    msg = GetActionChunk.Request()
    msg.prompt = request.prompt
    msg.robot_state.name = list(request.joint_names)
    msg.robot_state.position = np.asarray(request.joint_positions, dtype=float)
    msg.robot_state.header.stamp = time_msg(request.stamp)
    msg.image_names = list(request.images)
    msg.images = [rgb_to_image(pixels, image_encoding) for pixels in request.images.values()]
    msg.new_episode = bool(request.new_episode)
    msg.previous_action_chunk = array_to_multiarray(request.previous_action_chunk)
    if request.previous_anchor_positions is not None:
        msg.previous_anchor_state.name = list(request.joint_names)
        msg.previous_anchor_state.position = np.asarray(request.previous_anchor_positions, dtype=float)
    msg.frozen_prefix_steps = int(request.frozen_prefix_steps)
    msg.guidance_horizon = int(request.guidance_horizon)
    return msg


# --------------------------------------------------------------------------------------------
# Response conversion
# --------------------------------------------------------------------------------------------
def not_real_problem(values: NDArray[Any], joint_names: Sequence[str]) -> str | None:
    """The first value of a (steps, joints) chunk that is not a real number (a bool, a complex
    number, text, None), named by step and joint; None when all are. Such values are refused,
    never coerced (``True`` is not 1.0 rad, ``'1.5'`` is not 1.5, ``1+2j`` is not 1)."""
    if values.dtype.kind in "iuf":
        return None
    for (step, column), value in np.ndenumerate(values):
        value = value.item() if isinstance(value, np.generic) else value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"chunk step {step} joint '{joint_names[column]}' is {type(value).__name__} {value!r}, not a real number"
    return None


def validate_response(response: Any, joint_names: Sequence[str]) -> None:
    """Raise ``ResponseError`` unless ``response`` is a well-formed ``PolicyResponse`` for ``joint_names``."""
    if not isinstance(response, PolicyResponse):
        raise ResponseError(f"backend returned {type(response).__name__}, expected PolicyResponse")
    if not isinstance(response.status, PolicyStatus):
        raise ResponseError(f"backend returned status {response.status!r}, expected a PolicyStatus")
    if response.status is not PolicyStatus.CHUNK:
        return
    if response.actions is None:
        raise ResponseError("chunk is empty: the backend produced no actions")
    actions = np.asarray(response.actions)
    if actions.ndim != 2:
        raise ResponseError(f"chunk must be 2-D (steps, joints), got shape {actions.shape}")
    if actions.shape[0] == 0:
        raise ResponseError("chunk is empty: the backend produced no actions")
    if actions.shape[1] != len(joint_names):
        raise ResponseError(
            f"chunk has {actions.shape[1]} columns for {len(joint_names)} observed joints [{', '.join(joint_names)}]"
        )
    problem = not_real_problem(actions, joint_names)
    if problem is not None:
        raise ResponseError(problem)
    actions = actions.astype(float)
    bad = ~np.isfinite(actions)
    if bad.any():
        step, column = (int(i) for i in np.argwhere(bad)[0])
        raise ResponseError(f"chunk step {step} joint '{joint_names[column]}' is not finite ({actions[step, column]})")
    period = response.native_control_period
    if not isinstance(period, (int, float)) or not math.isfinite(period) or period < 0:
        raise ResponseError(f"native_control_period must be a finite number >= 0, got {period!r}")
    if response.policy_actions is not None:
        policy = np.asarray(response.policy_actions, dtype=float)
        if policy.ndim != 2 or policy.shape[0] != actions.shape[0]:
            raise ResponseError(
                f"policy_action_chunk must have one row per step ({actions.shape[0]}), got shape {policy.shape}"
            )
        if not np.all(np.isfinite(policy)):
            raise ResponseError("policy_action_chunk has non-finite values")


def response_to_msg(response: PolicyResponse, joint_names: Sequence[str]) -> GetActionChunk.Response:
    """Validate and convert; joint names are those of the request. Raises ``ResponseError``."""
    validate_response(response, joint_names)
    msg = GetActionChunk.Response()
    msg.status = _STATUS_TO_MSG[response.status]
    msg.message = response.message or ""
    if response.status is not PolicyStatus.CHUNK:
        return msg
    actions = np.asarray(response.actions, dtype=float)
    period = float(response.native_control_period)
    msg.chunk.joint_names = list(joint_names)
    points = []
    for step, row in enumerate(actions):
        point = JointTrajectoryPoint()
        point.positions = row
        point.time_from_start = duration_msg(step * period)  # informative only: the caller ignores it
        points.append(point)
    msg.chunk.points = points
    msg.native_control_period = period
    msg.policy_action_chunk = array_to_multiarray(response.policy_actions)
    return msg


def response_from_msg(msg: GetActionChunk.Response) -> PolicyResponse:
    """The inverse of ``response_to_msg`` (for recording served chunks and for tests).

    UNKNOWN reads as ERROR, as ExecutePolicy treats it.
    """
    if msg.status == GetActionChunk.Response.CHUNK_PRODUCED:
        actions = np.asarray([list(p.positions) for p in msg.chunk.points], dtype=float)
        return PolicyResponse.chunk(
            actions,
            float(msg.native_control_period),
            multiarray_to_array(msg.policy_action_chunk, "policy_action_chunk"),
            msg.message,
        )
    if msg.status == GetActionChunk.Response.NO_MORE_ACTIONS:
        return PolicyResponse.no_more_actions(msg.message)
    if msg.status == GetActionChunk.Response.ERROR:
        return PolicyResponse.error(msg.message)
    return PolicyResponse.error(msg.message or f"status UNKNOWN ({msg.status})")


def error_msg(reason: str) -> GetActionChunk.Response:
    """An ERROR response with ``reason`` as its message."""
    msg = GetActionChunk.Response()
    msg.status = GetActionChunk.Response.ERROR
    msg.message = reason
    return msg


# --------------------------------------------------------------------------------------------
# The adapter
# --------------------------------------------------------------------------------------------
class PolicyAdapter:
    """Answers GetActionChunk requests with a backend, never raising, always setting a status.

    The backend must already be loaded (``backend.load()``, and ``warmup`` for real models):
    the adapter only converts, calls and validates.
    """

    def __init__(self, backend: PolicyBackend, log_every: int = 50, logger: logging.Logger | None = None) -> None:
        if log_every <= 0:
            raise OptionError(f"log_every must be positive, got {log_every}")
        self.backend = backend
        self.log_every = log_every
        self.log = logger or logging.getLogger("policy.adapter")
        self.served_chunks = 0
        """CHUNK_PRODUCED answers so far."""
        self.errors = 0
        """ERROR answers so far (backend errors and contract violations alike)."""
        self.calls = 0
        self.last_message = ""
        """The message of the latest answer (the ERROR reason, the NO_MORE_ACTIONS note)."""
        self.service_name: str | None = None

    def handle(self, request_msg: GetActionChunk.Request) -> GetActionChunk.Response:
        """One service call: convert, infer, validate, convert back. Never raises."""
        self.calls += 1
        try:
            response = self._answer(request_msg)
        except BaseException as exc:  # the contract: any failure is ERROR with a reason
            if not raised_by_code(exc):
                raise
            response = error_msg(f"adapter failed: {describe_error(exc)}")
        self._account(response)
        return response

    def _answer(self, request_msg: GetActionChunk.Request) -> GetActionChunk.Response:
        try:
            request = request_from_msg(request_msg)
        except RequestError as exc:
            return error_msg(f"bad request: {exc}")
        name = getattr(self.backend, "name", type(self.backend).__name__)
        try:
            result = self.backend.infer(request)
        except BaseException as exc:  # sys.exit() and KeyboardInterrupt in a policy's code are its errors too
            if not raised_by_code(exc):
                raise
            return error_msg(f"policy backend '{name}' failed: {describe_error(exc)}")
        try:
            response = response_to_msg(result, request.joint_names)
        except ResponseError as exc:
            return error_msg(f"policy backend '{name}' returned an invalid answer: {exc}")
        if response.status == GetActionChunk.Response.ERROR and not response.message:
            response.message = f"policy backend '{name}' reported an error without a reason"
        if response.status == GetActionChunk.Response.NO_MORE_ACTIONS and not response.message:
            response.message = f"policy backend '{name}' has no more actions"
        return response

    def _account(self, response: GetActionChunk.Response) -> None:
        self.last_message = response.message
        if response.status == GetActionChunk.Response.CHUNK_PRODUCED:
            self.served_chunks += 1
            if self.served_chunks % self.log_every == 0:
                self.log.info("served %d chunks", self.served_chunks)
        elif response.status == GetActionChunk.Response.ERROR:
            self.errors += 1
            self.log.warning("answered ERROR: %s", response.message)
        else:
            self.log.info("answered NO_MORE_ACTIONS after %d chunks: %s", self.served_chunks, response.message)

    def serve(self, bus: Any, service_name: str = DEFAULT_SERVICE_NAME) -> PolicyAdapter:
        """Register ``handle`` as the GetActionChunk service ``service_name`` on ``bus``, on a
        thread of its own where the bus would run it on the thread that ticks a tree (a paced
        run's bus, ``own_thread``): inference never holds a tick."""
        bus.create_service(service_name, GetActionChunk, self.handle, own_thread=True)
        self.service_name = service_name
        return self
