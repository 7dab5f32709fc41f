"""The JSON wire format between the adapter node and the HTTP inference server. No pickle.

Why JSON and not pickle: the server accepts bodies from the network, and unpickling runs code.
JSON is parsed as data only, and every field below is checked before a backend sees it.

Arrays are objects ``{"dtype": D, "shape": [..], "data": B}``: ``D`` one of ``uint8``,
``float32``, ``float64``; ``B`` the base64 of the array's bytes, little-endian, C order.
Camera frames are ``uint8`` H x W x 3 RGB sent raw (lossless, no codec to agree on; about
200 KB per 224 x 224 frame, 1.2 MB per 640 x 480 frame once base64-encoded).

Request (``POST /infer`` body), the fields of ``PolicyRequest``::

    {"version": 1,
     "prompt": "stack the red cube on the blue cube",
     "joint_names": ["shoulder_pan_joint", ..., "robotiq_85_left_knuckle_joint"],
     "joint_positions": <float64 array (n,)>,
     "stamp": 12.34,                          # robot_state.header.stamp, seconds
     "image_names": ["scene"], "images": [<uint8 array (H, W, 3)>],   # index-aligned
     "new_episode": true,
     "previous_action_chunk": <float array (steps, dims)> | null,     # RTC carryover
     "previous_anchor_positions": <float64 array (n,)> | null,
     "frozen_prefix_steps": 0, "guidance_horizon": 0}

Response (``200`` body), the fields of ``PolicyResponse``::

    {"version": 1, "status": "chunk" | "no_more_actions" | "error", "message": "...",
     "actions": <float64 array (T, n)> | null, "native_control_period": 0.1,
     "policy_actions": <float64 array (T, A)> | null}

Any other answer (``4xx``/``5xx``) carries ``{"error": "<reason>"}``.

Decoding is strict: an unknown or missing field, a wrong type, an array whose bytes do not
match its shape, a non-finite number: ``WireError`` naming the field and what is wrong, which the
server answers as ``400`` and the adapter as ERROR. Contract checks that need the request
(one column per observed joint) stay in the adapter (``policy.adapter.validate_response``).
This module imports no ROS, so an inference environment without rclpy can use it.
"""
from __future__ import annotations

import base64
import binascii
import json
import math
import reprlib
from typing import Any

import numpy as np
from numpy.typing import NDArray

from runtime.errors import ObjectiveError

from .backend import PolicyRequest, PolicyResponse, PolicyStatus

WIRE_VERSION = 1
DEFAULT_MAX_BODY_BYTES = 32 * 1024 * 1024
"""Bodies above this are refused (``413``): three 640 x 480 frames take about 3.7 MB."""
CONTENT_TYPE = "application/json"

_DTYPES: dict[str, np.dtype[Any]] = {"uint8": np.dtype("u1"), "float32": np.dtype("<f4"), "float64": np.dtype("<f8")}
_FLOAT_DTYPES = ("float32", "float64")
_MAX_NDIM = 3
_MAX_DIMENSION = 2**31 - 1
"""The largest length of one array dimension (a frame, a chunk: far below it)."""

_REQUEST_FIELDS = {
    "version", "prompt", "joint_names", "joint_positions", "stamp", "image_names", "images",
    "new_episode", "previous_action_chunk", "previous_anchor_positions", "frozen_prefix_steps",
    "guidance_horizon",
}
_RESPONSE_FIELDS = {"version", "status", "message", "actions", "native_control_period", "policy_actions"}


class WireError(ObjectiveError, ValueError):
    """A body that is not a valid request or response; the message names the field."""


# --------------------------------------------------------------------------------------------
# Arrays
# --------------------------------------------------------------------------------------------
def encode_array(array: NDArray[Any]) -> dict[str, Any]:
    """``{"dtype", "shape", "data"}`` for a uint8 or float array (other dtypes become float64)."""
    data = np.asarray(array)
    if data.dtype == np.uint8:
        name = "uint8"
    elif data.dtype == np.float32:
        name = "float32"
    else:
        name = "float64"
    data = np.ascontiguousarray(data, dtype=_DTYPES[name])
    return {"dtype": name, "shape": list(data.shape), "data": base64.b64encode(data.tobytes()).decode("ascii")}


def decode_array(obj: Any, field: str, dtypes: tuple[str, ...] = ("uint8", "float32", "float64")) -> NDArray[Any]:
    """The array ``obj`` encodes; ``WireError`` naming ``field`` when anything does not add up."""
    if not isinstance(obj, dict) or set(obj) != {"dtype", "shape", "data"}:
        raise WireError(f"'{field}' must be an array object with exactly the keys dtype, shape, data")
    dtype, shape, data = obj["dtype"], obj["shape"], obj["data"]
    if dtype not in dtypes:
        raise WireError(f"'{field}' has dtype {dtype!r}, expected one of {', '.join(dtypes)}")
    if (
        not isinstance(shape, list)
        or len(shape) > _MAX_NDIM
        or not all(isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= _MAX_DIMENSION for n in shape)
    ):
        raise WireError(f"'{field}' shape must be a list of at most {_MAX_NDIM} integers from 0 to {_MAX_DIMENSION}, got {_clipped(shape)}")
    if not isinstance(data, str):
        raise WireError(f"'{field}' data must be a base64 string")
    try:
        raw = base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError):
        raise WireError(f"'{field}' data is not valid base64") from None
    itemsize = _DTYPES[dtype].itemsize
    expected = math.prod(shape) * itemsize
    if len(raw) != expected:
        raise WireError(f"'{field}' has {len(raw)} bytes of data, expected {expected} for shape {shape} of {dtype}")
    try:
        array = np.frombuffer(raw, dtype=_DTYPES[dtype]).reshape(shape)
    except ValueError:  # numpy refuses shapes whose dimensions multiply past its index range, even with a zero among them
        raise WireError(f"'{field}' shape {shape} is too large") from None
    if dtype in _FLOAT_DTYPES and not np.all(np.isfinite(array)):
        raise WireError(f"'{field}' has non-finite values")
    return array


# --------------------------------------------------------------------------------------------
# Requests
# --------------------------------------------------------------------------------------------
def encode_request(request: PolicyRequest) -> bytes:
    """The JSON body of ``POST /infer`` for ``request``."""
    body = {
        "version": WIRE_VERSION,
        "prompt": request.prompt,
        "joint_names": list(request.joint_names),
        "joint_positions": encode_array(np.asarray(request.joint_positions, dtype=float)),
        "stamp": float(request.stamp),
        "image_names": list(request.images),
        "images": [encode_array(np.asarray(pixels, dtype=np.uint8)) for pixels in request.images.values()],
        "new_episode": bool(request.new_episode),
        "previous_action_chunk": _optional(request.previous_action_chunk, float),
        "previous_anchor_positions": _optional(request.previous_anchor_positions, float),
        "frozen_prefix_steps": int(request.frozen_prefix_steps),
        "guidance_horizon": int(request.guidance_horizon),
    }
    return json.dumps(body, separators=(",", ":")).encode("utf-8")


def decode_request(body: bytes) -> PolicyRequest:
    """Parse and validate a ``POST /infer`` body; ``WireError`` says what is wrong."""
    obj = _load_object(body, "request", _REQUEST_FIELDS)
    prompt = _typed(obj, "prompt", str, "a string")
    names = obj["joint_names"]
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise WireError("'joint_names' must be a non-empty list of joint names")
    if len(set(names)) != len(names):
        raise WireError(f"'joint_names' lists a joint twice: [{', '.join(names)}]")
    positions = decode_array(obj["joint_positions"], "joint_positions", _FLOAT_DTYPES).astype(float)
    if positions.shape != (len(names),):
        raise WireError(f"'joint_positions' has shape {list(positions.shape)}, expected [{len(names)}] (one per joint name)")
    stamp = _finite_float(obj["stamp"])
    if stamp is None or stamp < 0:
        raise WireError(f"'stamp' must be a finite number of seconds >= 0, got {_clipped(obj['stamp'])}")
    image_names, images = obj["image_names"], obj["images"]
    if not isinstance(image_names, list) or not all(isinstance(n, str) and n for n in image_names):
        raise WireError("'image_names' must be a list of camera names")
    if not isinstance(images, list) or len(images) != len(image_names):
        count = len(images) if isinstance(images, list) else "no list of"
        raise WireError(f"'images' must be a list index-aligned with 'image_names': {count} images for {len(image_names)} names")
    if len(set(image_names)) != len(image_names):
        raise WireError(f"'image_names' lists a camera twice: [{', '.join(image_names)}]")
    pixels = {}
    for name, image in zip(image_names, images):
        field = f"images[{name}]"
        array = decode_array(image, field, ("uint8",))
        if array.ndim != 3 or array.shape[2] != 3 or array.shape[0] == 0 or array.shape[1] == 0:
            raise WireError(f"'{field}' must be a non-empty H x W x 3 RGB frame, got shape {list(array.shape)}")
        pixels[name] = array
    previous = obj["previous_action_chunk"]
    if previous is not None:
        previous = decode_array(previous, "previous_action_chunk", _FLOAT_DTYPES).astype(float)
        if previous.ndim != 2 or previous.shape[0] == 0:
            raise WireError(f"'previous_action_chunk' must be null or (steps, dims) with steps >= 1, got shape {list(previous.shape)}")
    anchor = obj["previous_anchor_positions"]
    if anchor is not None:
        anchor = decode_array(anchor, "previous_anchor_positions", _FLOAT_DTYPES).astype(float)
        if anchor.shape != (len(names),):
            raise WireError(f"'previous_anchor_positions' has shape {list(anchor.shape)}, expected [{len(names)}]")
    new_episode = _typed(obj, "new_episode", bool, "true or false")
    return PolicyRequest(
        prompt=prompt,
        joint_names=list(names),
        joint_positions=positions,
        images=pixels,
        new_episode=new_episode,
        previous_action_chunk=previous,
        previous_anchor_positions=anchor,
        frozen_prefix_steps=_count(obj, "frozen_prefix_steps"),
        guidance_horizon=_count(obj, "guidance_horizon"),
        stamp=float(stamp),
    )


# --------------------------------------------------------------------------------------------
# Responses
# --------------------------------------------------------------------------------------------
def encode_response(response: PolicyResponse) -> bytes:
    """The JSON body of a ``200`` answer; ``WireError`` if ``response`` cannot be encoded."""
    if not isinstance(response, PolicyResponse) or not isinstance(response.status, PolicyStatus):
        raise WireError(f"backend returned {response!r}, expected a PolicyResponse with a PolicyStatus")
    try:
        actions = _optional(response.actions, float)
        policy = _optional(response.policy_actions, float)
        period = float(response.native_control_period)
    except (TypeError, ValueError) as exc:
        raise WireError(f"backend answer cannot be encoded: {exc}") from None
    body = {
        "version": WIRE_VERSION,
        "status": response.status.value,
        "message": str(response.message or ""),
        "actions": actions,
        "native_control_period": period if math.isfinite(period) else None,
        "policy_actions": policy,
    }
    return json.dumps(body, separators=(",", ":")).encode("utf-8")


def decode_response(body: bytes) -> PolicyResponse:
    """Parse and validate a ``200`` body from the server; ``WireError`` says what is wrong."""
    obj = _load_object(body, "response", _RESPONSE_FIELDS)
    statuses = {s.value: s for s in PolicyStatus}
    status = statuses.get(obj["status"]) if isinstance(obj["status"], str) else None
    if status is None:
        raise WireError(f"'status' must be one of {', '.join(statuses)}, got {obj['status']!r}")
    message = _typed(obj, "message", str, "a string")
    period = _finite_float(obj["native_control_period"])
    if period is None or period < 0:
        raise WireError(f"'native_control_period' must be a finite number >= 0, got {_clipped(obj['native_control_period'])}")
    actions = obj["actions"]
    if actions is not None:
        actions = decode_array(actions, "actions", _FLOAT_DTYPES).astype(float)
        if actions.ndim != 2:
            raise WireError(f"'actions' must be (steps, joints), got shape {list(actions.shape)}")
    elif status is PolicyStatus.CHUNK:
        raise WireError("'actions' is null in a chunk answer: the server produced no actions")
    policy = obj["policy_actions"]
    if policy is not None:
        policy = decode_array(policy, "policy_actions", _FLOAT_DTYPES).astype(float)
        if policy.ndim != 2:
            raise WireError(f"'policy_actions' must be null or (steps, dims), got shape {list(policy.shape)}")
    return PolicyResponse(status, message, actions, float(period), policy)


def error_body(reason: str) -> bytes:
    """The body of a ``4xx``/``5xx`` answer."""
    return json.dumps({"error": reason}).encode("utf-8")


def read_error(body: bytes) -> str:
    """The reason in an error body, or a readable excerpt of whatever the server sent."""
    try:
        obj = json.loads(body)
    except (ValueError, UnicodeDecodeError, RecursionError):
        obj = None
    if isinstance(obj, dict) and isinstance(obj.get("error"), str):
        result: str = obj["error"]
        return result
    text = body[:200].decode("utf-8", "replace").strip()
    return text or "no reason given"


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------
def _finite_float(value: Any) -> float | None:
    """``value`` as a float when it is a finite JSON number (an integer too large for a float,
    such as 10**400, is not), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def _clipped(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for a message about a value of any size."""
    short = reprlib.Repr()
    short.maxlong, short.maxlist, short.maxother = limit, 8, limit
    text = short.repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _optional(array: Any, dtype: type) -> dict[str, Any] | None:
    return None if array is None else encode_array(np.asarray(array, dtype=dtype))


def _load_object(body: bytes, what: str, fields: set[str]) -> dict[str, Any]:
    try:
        obj = json.loads(body)
    except UnicodeDecodeError:
        raise WireError(f"{what} body is not UTF-8 text") from None
    except ValueError as exc:
        raise WireError(f"{what} body is not valid JSON ({exc})") from None
    except RecursionError:  # the decoder recurses once per nesting level: [[[[...]]]] exhausts the stack
        raise WireError(f"{what} body nests JSON arrays or objects too deeply") from None
    if not isinstance(obj, dict):
        raise WireError(f"{what} body must be a JSON object")
    if obj.get("version") != WIRE_VERSION:
        raise WireError(f"{what} 'version' must be {WIRE_VERSION}, got {obj.get('version')!r}")
    unknown = sorted(set(obj) - fields)
    if unknown:
        raise WireError(f"{what} has unknown fields: {', '.join(unknown)}")
    missing = sorted(fields - set(obj))
    if missing:
        raise WireError(f"{what} lacks fields: {', '.join(missing)}")
    return obj


def _typed(obj: dict[str, Any], field: str, kind: type, what: str) -> Any:
    value = obj[field]
    if not isinstance(value, kind):
        raise WireError(f"'{field}' must be {what}, got {type(value).__name__}")
    return value


def _count(obj: dict[str, Any], field: str) -> int:
    value = obj[field]
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**32:
        raise WireError(f"'{field}' must be an integer in [0, 2^32), got {value!r}")
    return value
