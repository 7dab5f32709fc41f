"""LeRobot backend: the guide's guidance-horizon conversion and the camera mapping as pure functions
(always run), then a tiny SmolVLA checkpoint served for real (skipped without `make lerobot`)."""
from __future__ import annotations

import importlib.util
import json
import logging

import numpy as np
import pytest

from policy.backend import PolicyRequest, PolicyStatus
from policy.lerobot_backend import (
    CameraMappingError,
    LatencyMonitor,
    checked_crop,
    crop_slices,
    execution_horizon,
    frame_to_rgb,
    joint_order,
    make_lerobot_backend,
    map_cameras,
    parse_camera_map,
    resolve_checkpoint,
)

KEYS = ["observation.images.scene", "observation.images.wrist", "observation.images.overview"]
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
          "wrist_3_joint", "robotiq_85_left_knuckle_joint"]
PROMPT = "stack the blue cube on the green cube"


# ---------------------------------------------------------------------------------------------
# Pure functions
# ---------------------------------------------------------------------------------------------
def test_guidance_horizon_zero_means_the_server_default_then_the_prefix_is_added():
    assert execution_horizon(frozen_prefix_steps=4, guidance_horizon=0, server_default=10) == 14
    assert execution_horizon(frozen_prefix_steps=0, guidance_horizon=0, server_default=10) == 10


def test_guidance_horizon_overrides_the_default_and_still_counts_past_the_prefix():
    assert execution_horizon(frozen_prefix_steps=4, guidance_horizon=18, server_default=10) == 22
    # A width smaller than the delay must not shrink the frozen prefix.
    assert execution_horizon(frozen_prefix_steps=7, guidance_horizon=2, server_default=10) == 9


@pytest.mark.parametrize("args, message", [
    ((-1, 0, 10), "frozen_prefix_steps must be >= 0, got -1"),
    ((0, -3, 10), "guidance_horizon must be >= 0, got -3"),
    ((0, 0, 0), "the server's default guidance horizon must be >= 1, got 0"),
])
def test_guidance_horizon_refuses_negative_or_empty_widths(args, message):
    with pytest.raises(ValueError, match=message):
        execution_horizon(*args)


def test_cameras_map_by_name_in_any_order():
    assert map_cameras(["wrist", "overview", "scene"], KEYS) == {
        "wrist": "observation.images.wrist",
        "overview": "observation.images.overview",
        "scene": "observation.images.scene",
    }


def test_cameras_map_explicitly_to_other_names_or_full_keys():
    keys = ["observation.images.top", "observation.images.hand"]
    assert map_cameras(["scene", "wrist"], keys, {"scene": "top", "wrist": "observation.images.hand"}) == {
        "scene": "observation.images.top", "wrist": "observation.images.hand",
    }
    assert parse_camera_map("scene=top; wrist=hand") == {"scene": "top", "wrist": "hand"}


def test_an_unknown_request_camera_is_refused_naming_both_sides():
    with pytest.raises(CameraMappingError) as err:
        map_cameras(["scene", "wirst", "overview"], KEYS)
    assert str(err.value) == (
        "request image 'wirst' is not a camera of the checkpoint: checkpoint cameras [scene, wrist, overview], "
        "request images [scene, wirst, overview]"
    )


def test_a_checkpoint_camera_left_unfed_is_refused_naming_both_sides():
    with pytest.raises(CameraMappingError) as err:
        map_cameras(["scene", "wrist"], KEYS)
    assert str(err.value) == (
        "checkpoint cameras [overview] get no request image: checkpoint cameras [scene, wrist, overview], "
        "request images [scene, wrist]"
    )


def test_two_request_images_into_one_camera_are_refused():
    with pytest.raises(CameraMappingError, match=r"checkpoint cameras \[scene\] are fed by more than one request image"):
        map_cameras(["scene", "front"], ["observation.images.scene"], {"front": "scene"})
    with pytest.raises(CameraMappingError, match=r"camera map names request images \[top\] that the request does not have"):
        map_cameras(["scene"], ["observation.images.scene"], {"top": "scene"})


def test_a_crop_is_the_same_whole_pixels_at_any_frame_size_and_bad_boxes_are_named():
    assert crop_slices(128, 128, (0.21875, 0.25, 0.71875, 0.75)) == (slice(28, 92), slice(32, 96))
    assert crop_slices(64, 64, (0.21875, 0.25, 0.71875, 0.75)) == (slice(14, 46), slice(16, 48))
    assert crop_slices(10, 10, (0.5, 0.5, 0.52, 0.52)) == (slice(5, 6), slice(5, 6))  # never empty
    assert checked_crop("overview", [0, 0.25, 1, 0.75]) == (0.0, 0.25, 1.0, 0.75)
    for box in ([0.5, 0, 0.4, 1], [0, 0, 1], [-0.1, 0, 1, 1], [0, 0, 1, 1.2]):
        with pytest.raises(ValueError, match=r"crop of camera 'overview' must be \[top, left, bottom, right\] fractions"):
            checked_crop("overview", box)


def test_bgr_frames_are_reversed_and_mono_replicated():
    bgr = np.zeros((2, 3, 3), dtype=np.uint8)
    bgr[..., 0] = 200  # blue in BGR
    assert frame_to_rgb(bgr, "bgr8")[0, 0].tolist() == [0, 0, 200]
    assert frame_to_rgb(np.full((2, 2), 7, dtype=np.uint8), "mono8").shape == (2, 2, 3)
    with pytest.raises(ValueError, match="image 'wrist': expected uint8 pixels, got float64"):
        frame_to_rgb(np.zeros((2, 2, 3)), "rgb8", "wrist")


def test_joint_order_maps_checkpoint_columns_and_names_both_lists_on_mismatch():
    assert joint_order(["b", "a", "c"], ["a", "b", "c"]) == [1, 0, 2]
    with pytest.raises(ValueError, match=r"checkpoint's joints \[a, b\] do not match the request's robot_state joints \[a, x\]"):
        joint_order(["a", "x"], ["a", "b"])


def test_latency_monitor_warns_once_when_steady_latency_passes_half_the_window():
    monitor = LatencyMonitor(committed_window=0.2, window=3)
    assert monitor.record(0.05) is None
    assert monitor.record(0.05) is None
    assert monitor.record(0.3) is None  # one slow call is not steady latency
    warning = monitor.record(0.3)
    assert warning.startswith("steady inference latency 300 ms exceeds half the committed window (200 ms)")
    assert monitor.record(0.3) is None


def test_bad_options_and_missing_checkpoints_are_named(tmp_path):
    with pytest.raises(ValueError, match="unknown LeRobot backend options bogus"):
        make_lerobot_backend(tmp_path, bogus=1)
    with pytest.raises(FileNotFoundError, match="is not a LeRobot checkpoint: no config.json"):
        resolve_checkpoint(tmp_path)


def test_record_demos_without_the_lerobot_extra_names_the_venv_that_has_it(tmp_path, capsys, monkeypatch):
    import sim.demos
    from runtime.app.cli import main

    def missing(options):
        raise ModuleNotFoundError("No module named 'torch'", name="torch")

    monkeypatch.setattr(sim.demos, "record_demos", missing)
    assert main(["record-demos", str(tmp_path / "demos"), "--episodes", "1"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: objective record-demos writes a LeRobot dataset: torch is not installed: it comes with the LeRobot "
        "extra, `make lerobot` in a checkout or pip install 'objective-runtime[lerobot]'")
    assert not (tmp_path / "demos").exists()


# ---------------------------------------------------------------------------------------------
# A real tiny SmolVLA (needs the LeRobot extra)
# ---------------------------------------------------------------------------------------------
needs_lerobot = pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None or importlib.util.find_spec("torch") is None,
    reason="the LeRobot extra is not installed (make lerobot)",
)
ACTION_MEAN = np.arange(7.0)
ACTION_STD = np.full(7, 2.0)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """A random-weight tiny SmolVLA saved in LeRobot's format with known action statistics."""
    from policy.tiny_smolvla import TinySmolVLASpec, build_tiny_smolvla, save_checkpoint

    folder = tmp_path_factory.mktemp("tiny_smolvla")
    spec = TinySmolVLASpec(image_size=64, num_steps=4)
    config, policy = build_tiny_smolvla(folder, spec)
    stats = {
        "observation.state": {"mean": np.zeros(7), "std": np.ones(7), "min": -np.ones(7), "max": np.ones(7)},
        "action": {"mean": ACTION_MEAN, "std": ACTION_STD, "min": -np.ones(7), "max": np.ones(7)},
    }
    save_checkpoint(folder, config, policy, stats, {"joint_names": JOINTS, "control_period": 0.1,
                                                    "default_guidance_horizon": 8})
    return folder


@pytest.fixture(scope="module")
def backend(checkpoint):
    served = make_lerobot_backend(checkpoint, committed_window=None)
    served.load()
    return served


def frames(size: int = 64) -> dict[str, np.ndarray]:
    return {name: np.full((size, size, 3), 90, dtype=np.uint8) for name in ("scene", "wrist", "overview")}


def spy_on_predict(backend, monkeypatch) -> list[dict]:
    calls: list[dict] = []
    original = backend.policy.predict_action_chunk

    def predict(batch, **kwargs):
        calls.append({"batch": batch, **kwargs})
        return original(batch, **kwargs)

    monkeypatch.setattr(backend.policy, "predict_action_chunk", predict)
    return calls


@needs_lerobot
def test_checkpoint_answers_a_denormalized_chunk_in_the_request_joint_order(backend, monkeypatch):
    response = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(), new_episode=True))
    assert response.status is PolicyStatus.CHUNK, response.message
    assert response.actions.shape == (50, 7) and response.policy_actions.shape == (50, 7)
    assert response.native_control_period == 0.1
    np.testing.assert_allclose(response.actions, response.policy_actions * ACTION_STD + ACTION_MEAN, atol=1e-5)

    reversed_joints = JOINTS[::-1]
    again = backend.infer(PolicyRequest(PROMPT, reversed_joints, np.zeros(7), frames()))
    # Column j of the answer is joint reversed_joints[j]: the checkpoint's last joint comes first.
    np.testing.assert_allclose(again.actions[:, ::-1], again.policy_actions * ACTION_STD + ACTION_MEAN, atol=1e-5)


@needs_lerobot
def test_frames_of_another_size_are_resized_to_the_checkpoint_features(backend, monkeypatch):
    calls = spy_on_predict(backend, monkeypatch)
    response = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(size=100)))
    assert response.status is PolicyStatus.CHUNK, response.message
    assert tuple(calls[0]["batch"]["observation.images.wrist"].shape) == (1, 3, 64, 64)


@pytest.fixture(scope="module")
def cropping_checkpoint(tmp_path_factory):
    """A two-camera tiny SmolVLA whose metadata crops the overview and ignores the scene image."""
    from policy.tiny_smolvla import TinySmolVLASpec, build_tiny_smolvla, save_checkpoint

    folder = tmp_path_factory.mktemp("cropping_smolvla")
    config, policy = build_tiny_smolvla(folder, TinySmolVLASpec(cameras=("wrist", "overview"), image_size=32,
                                                                patch_size=8, num_steps=2))
    stats = {key: {"mean": np.zeros(7), "std": np.ones(7), "min": -np.ones(7), "max": np.ones(7)}
             for key in ("observation.state", "action")}
    save_checkpoint(folder, config, policy, stats, {
        "joint_names": JOINTS, "control_period": 0.1, "camera_crops": {"overview": [0.5, 0.0, 1.0, 0.5]},
        "ignored_images": ["scene"],
    })
    return folder


@needs_lerobot
def test_metadata_crops_a_camera_before_the_resize_and_drops_only_the_ignored_images(cropping_checkpoint, monkeypatch):
    served = make_lerobot_backend(cropping_checkpoint, committed_window=None)
    served.load()
    assert served.describe()["camera_crops"] == {"overview": [0.5, 0.0, 1.0, 0.5]}
    calls = spy_on_predict(served, monkeypatch)
    overview = np.zeros((64, 64, 3), dtype=np.uint8)
    overview[32:, :32] = 255  # the cropped quarter is white, the rest black
    images = {"scene": np.zeros((64, 64, 3), np.uint8), "wrist": np.zeros((64, 64, 3), np.uint8), "overview": overview}
    response = served.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), images, new_episode=True))
    assert response.status is PolicyStatus.CHUNK, response.message
    seen = calls[0]["batch"]["observation.images.overview"]
    assert tuple(seen.shape[-2:]) == (32, 32) and float(seen.min()) > 0.99  # only the white quarter, at 32 px
    missing = served.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), {"scene": images["scene"], "overview": overview}))
    assert missing.status is PolicyStatus.ERROR and "checkpoint cameras [wrist] get no request image" in missing.message


@needs_lerobot
def test_noise_scale_zero_answers_one_chunk_per_observation_and_bad_metadata_values_are_named(checkpoint, backend, tmp_path):
    request = PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(), new_episode=True)
    later = PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames())  # the same observation, later in the episode
    sampled = [backend.infer(request).actions, backend.infer(later).actions]
    assert backend.describe()["noise_scale"] == 1.0
    assert np.abs(sampled[0] - sampled[1]).max() > 1e-3  # two samples of the flow differ
    # a new episode starts the noise from the seed again: its first chunk is the first episode's
    np.testing.assert_array_equal(backend.infer(request).actions, sampled[0])

    from policy.server import BackendOptions, make_backend

    central = make_backend("lerobot", BackendOptions(checkpoint=checkpoint, noise_scale=0.0))  # serve --noise-scale 0
    central.load()
    answers = [central.infer(request).actions for _ in range(2)]
    np.testing.assert_array_equal(answers[0], answers[1])
    assert central.describe()["noise_scale"] == 0.0

    import shutil

    copy = tmp_path / "central"
    shutil.copytree(checkpoint, copy)
    metadata = json.loads((copy / "objective_policy.json").read_text())
    (copy / "objective_policy.json").write_text(json.dumps({**metadata, "noise_scale": 0}))
    from_metadata = make_lerobot_backend(copy, committed_window=None)
    from_metadata.load()
    np.testing.assert_allclose(from_metadata.infer(request).actions, answers[0], atol=1e-6)

    (copy / "objective_policy.json").write_text(json.dumps({**metadata, "noise_scale": "loud"}))
    with pytest.raises(ValueError, match=r"objective_policy.json: noise_scale must be a finite number >= 0 .*'loud'"):
        make_lerobot_backend(copy, committed_window=None).load()
    with pytest.raises(ValueError, match=r"the noise_scale option: noise_scale must be a finite number >= 0 .*-1"):
        make_lerobot_backend(checkpoint, committed_window=None, noise_scale=-1).load()
    (copy / "objective_policy.json").write_text(json.dumps({**metadata, "action_range": {"min": [0.0]}}))
    with pytest.raises(ValueError, match=r"objective_policy.json: action_range must be .*min <= max, got \{'min': \[0.0\]\}"):
        make_lerobot_backend(copy, committed_window=None).load()
    (copy / "objective_policy.json").write_text(json.dumps({**metadata, "chunk_samples": 0}))
    with pytest.raises(ValueError, match=r"objective_policy.json: chunk_samples must be an integer >= 1, got 0"):
        make_lerobot_backend(copy, committed_window=None).load()


@needs_lerobot
def test_rtc_carryover_reaches_predict_action_chunk_with_the_converted_horizon(backend, monkeypatch):
    first = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(), new_episode=True))
    tail = first.policy_actions[20:]
    calls = spy_on_predict(backend, monkeypatch)

    guided = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(), previous_action_chunk=tail,
                                         frozen_prefix_steps=4, guidance_horizon=0))
    assert calls[-1]["inference_delay"] == 4
    assert calls[-1]["execution_horizon"] == 12  # 4 frozen + the checkpoint's default width 8
    np.testing.assert_array_equal(calls[-1]["prev_chunk_left_over"].numpy(), tail.astype(np.float32))
    # Guidance holds the frozen prefix to the carried tail (unguided, it would be fresh noise).
    assert np.abs(guided.policy_actions[:4] - tail[:4]).mean() < 0.1

    backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(), previous_action_chunk=tail,
                                frozen_prefix_steps=4, guidance_horizon=18))
    assert calls[-1]["execution_horizon"] == 22

    backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames()))
    assert "prev_chunk_left_over" not in calls[-1]  # no carryover: an unguided call


@needs_lerobot
def test_request_problems_answer_error_naming_both_sides(backend):
    wrong_cameras = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), {"scene": frames()["scene"]}))
    assert wrong_cameras.status is PolicyStatus.ERROR
    assert wrong_cameras.message == (
        "checkpoint cameras [wrist, overview] get no request image: checkpoint cameras [scene, wrist, overview], "
        "request images [scene]"
    )
    wrong_joints = backend.infer(PolicyRequest(PROMPT, JOINTS[:6] + ["finger"], np.zeros(7), frames()))
    assert wrong_joints.status is PolicyStatus.ERROR and "do not match the request's robot_state joints" in wrong_joints.message
    wrong_tail = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(), previous_action_chunk=np.zeros((10, 3)),
                                             frozen_prefix_steps=2))
    assert wrong_tail.message == (
        "previous_action_chunk has shape (10, 3); this policy's normalized actions are (steps, 7) "
        "(echo policy_action_chunk back untouched)"
    )


@needs_lerobot
def test_warmup_on_load_and_the_latency_warning(checkpoint, caplog):
    served = make_lerobot_backend(checkpoint, warmup_on_load=True, committed_window=1e-4)
    with caplog.at_level(logging.WARNING, logger="objective.policy.lerobot"):
        served.load()
    assert served.calls == 2  # the full-size warmup ran inside load()
    assert any("exceeds half the committed window (0 ms)" in r.message for r in caplog.records)
    assert served.describe()["cameras"] == ["scene", "wrist", "overview"]


@needs_lerobot
def test_objective_serve_backend_lerobot_answers_over_http_with_the_rtc_echo(checkpoint):
    from policy.http_client import ClientConfig, HttpBackend
    from policy.server import BackendOptions, InferenceServer, ServerConfig, make_backend

    with pytest.raises(ValueError, match="--backend lerobot needs --checkpoint DIR"):
        make_backend("lerobot", BackendOptions())
    backend = make_backend("lerobot", BackendOptions(checkpoint=checkpoint, default_guidance=6))
    # The server's generic warmup (one 224 px 'scene' view) does not fit the checkpoint: the
    # backend warms up on its own full-size observation instead of failing to become ready.
    server = InferenceServer(backend, ServerConfig(key="k" * 32)).start()
    try:
        assert server.ready.wait(60), server.message
        client = HttpBackend(ClientConfig(server.url + "/infer", timeout=30, key="k" * 32))
        first = client.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(), new_episode=True))
        assert first.status is PolicyStatus.CHUNK and first.policy_actions.shape == (50, 7)
        client.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(), previous_action_chunk=first.policy_actions[10:],
                                   frozen_prefix_steps=3))
        assert backend.last_rtc is not None
        assert (backend.last_rtc.inference_delay, backend.last_rtc.execution_horizon, backend.last_rtc.leftover_steps) == (3, 9, 40)
    finally:
        server.stop()


@pytest.fixture(scope="module")
def calm_checkpoint(tmp_path_factory):
    """A random-weight tiny SmolVLA whose denormalized actions stay within a milliradian of Home,
    so ExecutePolicy executes its chunks (no limit rejections) and the RTC loop can be watched."""
    from policy.tiny_smolvla import TinySmolVLASpec, build_tiny_smolvla, save_checkpoint
    from sim.robot_model import ARM_JOINTS, load_waypoints

    folder = tmp_path_factory.mktemp("calm_smolvla")
    config, policy = build_tiny_smolvla(folder, TinySmolVLASpec(image_size=32, num_steps=4))
    home = load_waypoints()["Home"]
    mean = np.array([home[j] for j in ARM_JOINTS] + [0.0])
    stats = {
        "observation.state": {"mean": mean, "std": np.ones(7), "min": mean - 1, "max": mean + 1},
        "action": {"mean": mean, "std": np.full(7, 1e-3), "min": mean - 1, "max": mean + 1},
    }
    save_checkpoint(folder, config, policy, stats, {"joint_names": JOINTS, "control_period": 0.1})
    return folder


@needs_lerobot
def test_stack_cubes_lerobot_objective_carries_the_rtc_tail_into_predict_action_chunk(calm_checkpoint, monkeypatch, capsys):
    """The shipped Objective headless with RTC on: every guided call gets ExecutePolicy's frozen
    prefix as inference_delay, frozen prefix + 18 (the Objective's guidance_horizon) as
    execution_horizon, and as prev_chunk_left_over the unexecuted tail of the previous chunk's
    normalized output, untouched, starting at the request instant."""
    import json

    from runtime.app.cli import main
    from policy.lerobot_backend import LeRobotBackend

    calls: list[dict] = []
    original_load = LeRobotBackend.load

    requests: list[PolicyRequest] = []

    def load_and_spy(self):
        original_load(self)
        predict, infer = self.policy.predict_action_chunk, self.infer

        def spy(batch, **kwargs):
            output = predict(batch, **kwargs)
            calls.append({**kwargs, "output": output[0].detach().numpy().copy(), "request": requests[-1]})
            return output

        def keep_request(request):
            requests.append(request)
            return infer(request)

        self.policy.predict_action_chunk = spy
        self.infer = keep_request

    monkeypatch.setattr(LeRobotBackend, "load", load_and_spy)
    code = main(["run", "objectives/stack_cubes_lerobot.xml", "--world", "kinematic", "--seed", "1",
                 "--policy", f"lerobot:{calm_checkpoint}", "--policy-latency", "0.3", "--json"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    # A random policy holding Home stacks nothing: the run fails at the check, not in ExecutePolicy.
    assert code == 1 and summary["failing_node"] == "top cube on bottom cube", summary["reason"]
    assert summary["execute_policy"]["steps_executed"] == 250 and summary["execute_policy"]["rejections"] == 0

    guided = [i for i, call in enumerate(calls) if "prev_chunk_left_over" in call]
    assert len(guided) >= 10
    for i in guided:
        call, previous = calls[i], calls[i - 1]["output"]
        tail = call["prev_chunk_left_over"].numpy()
        request = call["request"]
        assert request.frozen_prefix_steps >= 3  # 0.3 s of latency at dt 0.1, plus ExecutePolicy's margin
        assert call["inference_delay"] == request.frozen_prefix_steps
        assert request.guidance_horizon == 18
        assert call["execution_horizon"] == request.frozen_prefix_steps + 18
        # The tail is the previous chunk's unexecuted remainder from this request's instant on.
        np.testing.assert_array_equal(tail, previous[len(previous) - len(tail):].astype(np.float32))
        assert 0 < len(tail) < len(previous)


@needs_lerobot
def test_record_demos_writes_a_lerobot_dataset_of_oracle_steps(tmp_path, capsys):
    from policy.lerobot_offline import force_offline

    force_offline()  # before anything imports lerobot
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from runtime.app.cli import main

    out = tmp_path / "demos"
    code = main(["record-demos", str(out), "--episodes", "1", "--seed", "3", "--world", "kinematic",
                 "--image-size", "32", "--steps", "30", "--keep-failed"])
    assert code == 0
    assert capsys.readouterr().out.strip() == f"{out}: 1 episodes, 30 frames from world 'kinematic'"
    dataset = LeRobotDataset("local/stack_cubes_demos", root=out)
    assert dataset.meta.fps == 10 and dataset.meta.total_frames == 30
    assert dataset.meta.features["action"]["names"] == JOINTS
    frame = dataset[5]
    assert frame["task"] == PROMPT
    assert tuple(frame["observation.images.wrist"].shape) == (3, 32, 32)
    # The label is the oracle's target for that instant, next to where the arm actually is.
    assert np.abs(frame["action"].numpy() - frame["observation.state"].numpy()).max() < 0.1
    assert main(["record-demos", str(out), "--episodes", "1"]) == 2
    assert "already exists (pass --overwrite to replace it)" in capsys.readouterr().err


@needs_lerobot
def test_record_demos_keeps_the_chosen_cameras_and_stops_after_the_plan_with_demo_only_settings(tmp_path, capsys):
    """Two cameras, a slower gripper, motion noise and frames only until 1 s after the plan: the
    dataset has those cameras, meta/demos.json the settings, and fewer frames than --steps."""
    import json

    from runtime.app.cli import main

    out = tmp_path / "demos"
    code = main(["record-demos", str(out), "--episodes", "1", "--seed", "3", "--world", "kinematic", "--image-size", "32",
                 "--steps", "250", "--keep-failed", "--cameras", "wrist,overview", "--gripper-velocity", "0.5",
                 "--motion-noise", "0.03", "--hold-after-plan", "1"])
    assert code == 0, capsys.readouterr().err
    info = json.loads((out / "meta" / "info.json").read_text())
    assert sorted(k for k in info["features"] if k.startswith("observation.images.")) == [
        "observation.images.overview", "observation.images.wrist"]
    demos = json.loads((out / "meta" / "demos.json").read_text())
    assert demos["cameras"] == ["wrist", "overview"] and demos["gripper_velocity"] == 0.5
    assert demos["motion_noise_rad"] == 0.03 and demos["hold_after_plan_s"] == 1
    assert 100 < info["total_frames"] < 250
    assert main(["record-demos", str(tmp_path / "bad"), "--cameras", "wrist,top"]) == 2
    assert "--cameras must name distinct cameras of scene, wrist, overview, got wrist, top" in capsys.readouterr().err


@needs_lerobot
def test_training_schedule_anneals_by_either_budget_and_early_frames_take_their_share_of_a_batch():
    import runpy
    from pathlib import Path

    import torch

    train = runpy.run_path(str(Path(__file__).resolve().parent.parent / "tools" / "train_tiny_smolvla.py"))
    factor = train["learning_rate_factor"]
    assert factor(0, 10, 0.0) == pytest.approx(0.1) and factor(10, 10, 0.0) == 1.0
    assert factor(50, 10, 0.5) == pytest.approx(0.5) and factor(99, 10, 1.0) == 0.0 and factor(99, 10, 1.7) == 0.0
    early = torch.arange(5)
    rows = train["sample_rows"](1000, 16, [(early, 0.375)], torch.Generator().manual_seed(0))
    assert len(rows) == 16 and bool((rows[-6:] < 5).all())
    uniform = train["sample_rows"](1000, 16, [(early, 0.0)], torch.Generator().manual_seed(0))
    assert len(uniform) == 16 and int((uniform < 5).sum()) < 6


@needs_lerobot
def test_the_training_pipeline_records_trains_saves_and_evaluates_in_one_command(tmp_path):
    """`make lerobot-policy` in miniature: record (two workers), train a few steps, save, evaluate."""
    import json
    import runpy
    from pathlib import Path

    train = runpy.run_path(str(Path(__file__).resolve().parent.parent / "tools" / "train_tiny_smolvla.py"))
    dataset, out = tmp_path / "demos", tmp_path / "policy"
    code = train["main"]([
        "--dataset", str(dataset), "--out", str(out), "--episodes", "2", "--demo-seed", "0", "--world", "kinematic", "--image-size", "32",
        "--record-steps", "30", "--keep-failed", "--workers", "2", "--steps", "3", "--batch", "4",
        "--eval-episodes", "1", "--eval-seed-start", "100",
    ])
    assert code == 0
    demos = json.loads((dataset / "meta" / "demos.json").read_text())
    assert demos["seeds"] == [0, 1] and demos["world"] == "kinematic"
    training = json.loads((out / "objective_policy.json").read_text())["training"]
    assert training["steps"] == 3 and training["episode_seeds"] == [0, 1] and training["seed"] == 0
    assert training["data_sha256"] == train["dataset_hash"](dataset) and len(training["data_sha256"]) == 64
    evaluation = json.loads((tmp_path / "policy.eval" / "evaluation.json").read_text())
    assert sorted(p.name for p in out.iterdir() if p.name.startswith("eval")) == []  # the checkpoint's hash stays its own
    assert evaluation["summary"]["episodes"] == 1 and "--seed-start 100" in evaluation["command"]
    assert "--policy lerobot:" in evaluation["command"] and "--world kinematic" in evaluation["command"]
    # The checkpoint serves: one chunk of the saved policy, in the request's joint order.
    backend = make_lerobot_backend(out, committed_window=None)
    backend.load()
    response = backend.infer(PolicyRequest(PROMPT, JOINTS, np.zeros(7), frames(32), new_episode=True))
    assert response.status == PolicyStatus.CHUNK and response.actions.shape == (50, 7)
