"""The GetActionChunk adapter: conversions, image encodings, and every failure answered as ERROR."""
from __future__ import annotations

import logging

import numpy as np
import pytest
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image

from runtime.io.bus import InProcessBus
from runtime.io.clock import SimClock
from policy.adapter import (
    PolicyAdapter,
    array_to_multiarray,
    multiarray_to_array,
    request_from_msg,
    request_to_msg,
    response_from_msg,
)
from policy.backend import PolicyRequest, PolicyResponse, PolicyStatus
from policy.images import ImageError, image_to_rgb, rgb_to_image

from .fakes import FakeBackend

ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
GRIPPER = "robotiq_85_left_knuckle_joint"
R = GetActionChunk.Response


def request_msg(names=ARM + [GRIPPER], images=None, **fields) -> GetActionChunk.Request:
    positions = np.linspace(-1.0, 1.0, len(names))
    req = PolicyRequest(prompt="stack the blue cube on the green cube", joint_names=list(names),
                        joint_positions=positions, images=images or {}, **fields)
    return request_to_msg(req)


def echo_chunk(steps=5):
    return lambda request: PolicyResponse.chunk(
        np.tile(request.joint_positions, (steps, 1)) + np.arange(steps)[:, None] * 0.01, 0.1
    )


# ---------------------------------------------------------------------------------------------
# Images
# ---------------------------------------------------------------------------------------------
def test_rgb8_round_trip_keeps_pixels():
    pixels = np.random.default_rng(0).integers(0, 255, (4, 5, 3), dtype=np.uint8)
    msg = rgb_to_image(pixels)
    assert (msg.encoding, msg.height, msg.width, msg.step) == ("rgb8", 4, 5, 15)
    assert np.array_equal(image_to_rgb(msg, "scene"), pixels)


def test_bgr8_is_converted_to_rgb():
    msg = Image(height=1, width=2, encoding="bgr8", step=6)
    msg.data = bytes([10, 20, 30, 1, 2, 3])  # two pixels, stored blue, green, red
    rgb = image_to_rgb(msg, "wrist")
    assert rgb.tolist() == [[[30, 20, 10], [3, 2, 1]]]
    assert np.array_equal(image_to_rgb(rgb_to_image(rgb, "bgr8")), rgb)


def test_mono8_becomes_three_equal_channels_and_padding_is_dropped():
    msg = Image(height=2, width=2, encoding="mono8", step=4)  # 2 bytes of padding per row
    msg.data = bytes([7, 8, 0, 0, 9, 10, 0, 0])
    rgb = image_to_rgb(msg)
    assert rgb.shape == (2, 2, 3)
    assert rgb[:, :, 0].tolist() == [[7, 8], [9, 10]]
    assert np.array_equal(rgb[:, :, 0], rgb[:, :, 2])


@pytest.mark.parametrize(
    "fields, reason",
    [
        (dict(encoding="rgba16", step=6, data=bytes(12)), "image 'overview': unsupported encoding 'rgba16'"),
        (dict(encoding="rgb8", step=5, data=bytes(10)), "image 'overview': step 5 is smaller than width 2 x 3 channel(s) = 6 bytes"),
        (dict(encoding="rgb8", step=6, data=bytes(11)), "image 'overview': data has 11 bytes, expected step 6 x height 2 = 12"),
    ],
)
def test_bad_frames_name_the_image(fields, reason):
    msg = Image(height=2, width=2, **{k: v for k, v in fields.items() if k != "data"})
    msg.data = fields["data"]
    with pytest.raises(ImageError) as err:
        image_to_rgb(msg, "overview")
    assert str(err.value).startswith(reason)


# ---------------------------------------------------------------------------------------------
# Request / response conversion
# ---------------------------------------------------------------------------------------------
def test_request_conversion_keeps_every_field():
    images = {"scene": np.full((3, 4, 3), 5, np.uint8), "wrist": np.zeros((2, 2, 3), np.uint8)}
    tail = np.arange(12.0).reshape(4, 3)
    msg = request_msg(images=images, new_episode=True, previous_action_chunk=tail,
                      previous_anchor_positions=np.arange(7.0), frozen_prefix_steps=3, guidance_horizon=18)
    req = request_from_msg(msg)
    assert req.joint_names == ARM + [GRIPPER]
    assert req.joint_positions.tolist() == pytest.approx(np.linspace(-1, 1, 7).tolist())
    assert list(req.images) == ["scene", "wrist"] and req.images["scene"].shape == (3, 4, 3)
    assert req.new_episode is True
    assert np.array_equal(req.previous_action_chunk, tail)
    assert req.previous_anchor_positions.tolist() == list(range(7))
    assert (req.frozen_prefix_steps, req.guidance_horizon) == (3, 18)


def test_multiarray_layout_is_steps_first_with_zero_offset():
    msg = array_to_multiarray(np.ones((4, 7)))
    assert [d.size for d in msg.layout.dim] == [4, 7] and msg.layout.data_offset == 0
    assert multiarray_to_array(msg).shape == (4, 7)
    msg.layout.data_offset = 3  # the contract: a non-zero offset reads as empty
    assert multiarray_to_array(msg) is None
    assert multiarray_to_array(array_to_multiarray(None)) is None


def test_empty_rtc_fields_read_as_none():
    req = request_from_msg(request_msg())
    assert req.previous_action_chunk is None and req.previous_anchor_positions is None


# ---------------------------------------------------------------------------------------------
# The adapter
# ---------------------------------------------------------------------------------------------
def test_chunk_echoes_robot_state_names_and_counts():
    adapter = PolicyAdapter(FakeBackend(echo_chunk(5)))
    response = adapter.handle(request_msg())
    assert response.status == R.CHUNK_PRODUCED
    assert list(response.chunk.joint_names) == ARM + [GRIPPER]
    assert len(response.chunk.points) == 5
    assert list(response.chunk.points[1].positions) == pytest.approx((np.linspace(-1, 1, 7) + 0.01).tolist())
    assert response.native_control_period == 0.1
    assert len(response.policy_action_chunk.data) == 0  # RTC not used: left empty
    assert adapter.served_chunks == 1 and adapter.errors == 0


def test_backend_exception_answers_error_with_the_reason():
    adapter = PolicyAdapter(FakeBackend(RuntimeError("CUDA out of memory")))
    response = adapter.handle(request_msg())
    assert response.status == R.ERROR
    assert response.message == "policy backend 'fake' failed: RuntimeError: CUDA out of memory"
    assert adapter.errors == 1 and adapter.served_chunks == 0


def test_nan_in_actions_answers_error_naming_step_and_joint():
    def nan_chunk(request):
        actions = np.zeros((4, 7))
        actions[2, 1] = np.nan
        return PolicyResponse.chunk(actions, 0.1)

    response = PolicyAdapter(FakeBackend(nan_chunk)).handle(request_msg())
    assert response.status == R.ERROR
    assert response.message == (
        "policy backend 'fake' returned an invalid answer: chunk step 2 joint 'shoulder_lift_joint' is not finite (nan)"
    )


def test_wrong_column_count_answers_error():
    response = PolicyAdapter(FakeBackend(PolicyResponse.chunk(np.zeros((4, 6)), 0.1))).handle(request_msg())
    assert response.status == R.ERROR
    assert response.message == (
        "policy backend 'fake' returned an invalid answer: chunk has 6 columns for 7 observed joints "
        f"[{', '.join(ARM + [GRIPPER])}]"
    )


@pytest.mark.parametrize(
    "answer, reason",
    [
        (PolicyResponse(PolicyStatus.CHUNK, actions=None), "chunk is empty: the backend produced no actions"),
        (PolicyResponse.chunk(np.zeros((0, 7)), 0.1), "chunk is empty: the backend produced no actions"),
        ({"actions": [[0.0] * 7]}, "backend returned dict, expected PolicyResponse"),
        (PolicyResponse.chunk(np.zeros((3, 7)), float("nan")), "native_control_period must be a finite number >= 0, got nan"),
        (PolicyResponse.chunk(np.zeros((3, 7)), 0.1, policy_actions=np.zeros((2, 7))),
         "policy_action_chunk must have one row per step (3), got shape (2, 7)"),
    ],
)
def test_invalid_answers_are_errors(answer, reason):
    response = PolicyAdapter(FakeBackend(answer)).handle(request_msg())
    assert response.status == R.ERROR
    assert response.message == f"policy backend 'fake' returned an invalid answer: {reason}"


def _with(value, column: int = 2) -> np.ndarray:
    """A 3-step chunk of zeros whose step 1, ``column`` holds ``value`` (its dtype what numpy makes of it)."""
    rows = [[0.0] * 7 for _ in range(3)]
    rows[1][column] = value
    return np.array(rows, dtype=object if isinstance(value, (bool, str, type(None))) else None)


STEP_1_ELBOW, FIRST = "chunk step 1 joint 'elbow_joint'", "chunk step 0 joint 'shoulder_pan_joint'"


@pytest.mark.parametrize("actions, problem", [
    (_with(1 + 2j), f"{FIRST} is complex 0j"),  # one complex value makes the whole array complex
    (_with(True), f"{STEP_1_ELBOW} is bool True"),
    (np.ones((3, 7), dtype=bool), f"{FIRST} is bool True"),
    (_with("1.5"), f"{STEP_1_ELBOW} is str '1.5'"),
    (np.full((3, 7), "0.1"), f"{FIRST} is str '0.1'"),
    (_with(None), f"{STEP_1_ELBOW} is NoneType None"),
], ids=["complex", "bool", "bool-array", "text", "text-array", "none"])
def test_values_that_are_not_real_numbers_are_refused_naming_step_and_joint(actions, problem):
    """On main they were coerced: the imaginary part dropped, True read as 1.0 rad, '1.5' as 1.5."""
    response = PolicyAdapter(FakeBackend(PolicyResponse.chunk(actions, 0.1))).handle(request_msg())
    assert response.status == R.ERROR
    assert response.message == f"policy backend 'fake' returned an invalid answer: {problem}, not a real number"


def test_bad_request_is_an_error_not_an_exception():
    msg = request_msg()
    msg.robot_state.position = [0.0] * 6
    backend = FakeBackend(echo_chunk())
    response = PolicyAdapter(backend).handle(msg)
    assert response.status == R.ERROR
    assert response.message == "bad request: robot_state has 7 names but 6 positions"
    assert backend.requests == []


def test_mismatched_image_lists_are_an_error():
    msg = request_msg(images={"scene": np.zeros((2, 2, 3), np.uint8)})
    msg.image_names = ["scene", "wrist"]
    response = PolicyAdapter(FakeBackend(echo_chunk())).handle(msg)
    assert response.message == "bad request: 1 images but 2 image_names (they must be index-aligned)"


def test_backend_error_and_end_of_stream_pass_through():
    assert PolicyAdapter(FakeBackend(PolicyResponse.error("model still loading"))).handle(request_msg()).message == "model still loading"
    silent = PolicyAdapter(FakeBackend(PolicyResponse.error(""))).handle(request_msg())
    assert (silent.status, silent.message) == (R.ERROR, "policy backend 'fake' reported an error without a reason")
    end = PolicyAdapter(FakeBackend(PolicyResponse.no_more_actions("replay finished"))).handle(request_msg())
    assert (end.status, end.message) == (R.NO_MORE_ACTIONS, "replay finished")


def test_rtc_chunk_is_sent_steps_first():
    answer = PolicyResponse.chunk(np.zeros((3, 7)), 0.02, policy_actions=np.arange(24.0).reshape(3, 8))
    response = PolicyAdapter(FakeBackend(answer)).handle(request_msg())
    layout = response.policy_action_chunk.layout
    assert [d.size for d in layout.dim] == [3, 8] and layout.data_offset == 0
    assert np.array_equal(response_from_msg(response).policy_actions, np.arange(24.0).reshape(3, 8))


def test_log_line_every_n_chunks(caplog):
    adapter = PolicyAdapter(FakeBackend(echo_chunk()), log_every=2)
    with caplog.at_level(logging.INFO, logger="policy.adapter"):
        for _ in range(4):
            adapter.handle(request_msg())
    assert [r.getMessage() for r in caplog.records] == ["served 2 chunks", "served 4 chunks"]


def test_serves_on_the_in_process_bus():
    clock = SimClock()
    bus = InProcessBus(clock)
    adapter = PolicyAdapter(FakeBackend(echo_chunk(3))).serve(bus)
    client = bus.create_client("/get_action_chunk", GetActionChunk)
    assert client.service_is_ready()
    future = client.call_async(request_msg())
    clock.advance(1.0)
    bus.spin_once()
    assert future.done()
    assert future.result().status == R.CHUNK_PRODUCED
    assert adapter.service_name == "/get_action_chunk" and adapter.served_chunks == 1
    bus.close()  # the service's worker thread ends with the bus
