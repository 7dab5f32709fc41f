"""Replay backend: recorded chunks served in order, then NO_MORE_ACTIONS; recording a run."""
from __future__ import annotations

import numpy as np
import pytest
from moveit_pro_ml_msgs.srv import GetActionChunk

from policy.adapter import PolicyAdapter, request_to_msg
from policy.backend import PolicyRequest, PolicyResponse, PolicyStatus
from policy.replay import (
    RecordedChunk,
    RecordingBackend,
    ReplayBackend,
    ReplayFileError,
    read_replay,
    write_replay,
)

NAMES = ["j1", "j2", "gripper"]
R = GetActionChunk.Response


def request(new_episode=False, names=NAMES) -> PolicyRequest:
    return PolicyRequest("", list(names), np.zeros(len(names)), new_episode=new_episode)


@pytest.fixture
def replay_file(tmp_path):
    path = tmp_path / "run.jsonl"
    write_replay(path, [RecordedChunk(NAMES, np.full((4, 3), float(i)), 0.0) for i in range(3)])
    return path


def test_serves_chunks_in_order_then_no_more_actions(replay_file):
    backend = ReplayBackend(replay_file)
    backend.load()
    adapter = PolicyAdapter(backend)
    answers = [adapter.handle(request_to_msg(request(new_episode=(i == 0)))) for i in range(4)]
    assert [a.status for a in answers] == [R.CHUNK_PRODUCED] * 3 + [R.NO_MORE_ACTIONS]
    assert [a.chunk.points[0].positions[0] for a in answers[:3]] == [0.0, 1.0, 2.0]
    assert answers[0].native_control_period == 0.0  # a replay reports no training rate
    assert answers[3].message == "replay of 'run.jsonl' finished after 3 chunks"
    assert adapter.served_chunks == 3


def test_new_episode_rewinds(replay_file):
    backend = ReplayBackend(replay_file)
    backend.load()
    backend.infer(request(new_episode=True))  # ExecutePolicy's discarded warmup call
    first = backend.infer(request(new_episode=True))  # the run's first real request
    assert first.actions[0, 0] == 0.0


def test_joint_mismatch_names_both_lists(replay_file):
    backend = ReplayBackend(replay_file)
    backend.load()
    answer = backend.infer(request(names=["j1", "j2", "finger"]))
    assert answer.status is PolicyStatus.ERROR
    assert answer.message == (
        "replay chunk 0: recorded joints [j1, j2, gripper] do not match the request's robot_state joints [j1, j2, finger]"
    )


def test_same_joints_in_another_order_are_reordered(tmp_path):
    path = tmp_path / "r.jsonl"
    write_replay(path, [RecordedChunk(NAMES, np.array([[1.0, 2.0, 3.0]]), 0.1)])
    backend = ReplayBackend(path)
    backend.load()
    answer = backend.infer(request(names=["gripper", "j1", "j2"]))
    assert answer.actions.tolist() == [[3.0, 1.0, 2.0]]
    assert answer.native_control_period == 0.1


@pytest.mark.parametrize(
    "line, reason",
    [
        ("{not json", "not valid JSON"),
        ('{"joint_names": [], "actions": [[1]]}', "'joint_names' must be a non-empty list of strings"),
        ('{"joint_names": ["a", "b"], "actions": [[1.0]]}', "'actions' must be a non-empty list of rows with 2 values each, got shape (1, 1)"),
        ('{"joint_names": ["a"], "actions": [[NaN]]}', "'actions' has non-finite values"),
    ],
)
def test_bad_files_name_file_and_line(tmp_path, line, reason):
    path = tmp_path / "bad.jsonl"
    path.write_text("# recorded by hand\n" + line + "\n")
    with pytest.raises(ReplayFileError) as err:
        read_replay(path)
    assert str(err.value).startswith(f"{path}:2: {reason}")


def test_missing_file_fails_at_load(tmp_path):
    with pytest.raises(ReplayFileError, match="replay file not found"):
        ReplayBackend(tmp_path / "nope.jsonl").load()


def test_recording_backend_writes_a_replayable_file(tmp_path):
    class Counter:
        name = "counter"

        def __init__(self):
            self.calls = 0

        def load(self): ...

        def warmup(self, example_request): ...

        def infer(self, request):
            self.calls += 1
            return PolicyResponse.chunk(np.full((2, 3), float(self.calls)), 0.1)

    path = tmp_path / "rec.jsonl"
    recorder = RecordingBackend(Counter(), path)
    recorder.infer(request(new_episode=True))  # warmup: dropped by the next new_episode
    for i in range(3):
        recorder.infer(request(new_episode=(i == 0)))
    chunks = read_replay(path)
    assert [c.actions[0, 0] for c in chunks] == [2.0, 3.0, 4.0]
    assert chunks[0].joint_names == NAMES and chunks[0].native_control_period == 0.1
