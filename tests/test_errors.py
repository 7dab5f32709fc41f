"""One root error: the user's mistakes (ERROR, exit 2, "error:") apart from the project's bugs
("internal error:", pointing at the crash report); failures grouped by their kind, not their text."""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

import runtime.app.world
from runtime.app.cli import main
from runtime.errors import INTERNAL, InternalError, ObjectiveError, ObjectiveRuntimeError, OptionError, SetupError
from tests.data.nodes import make_registry


@pytest.fixture(scope="module")
def registry():
    return make_registry()


def robot_tree(tmp_path: Path) -> Path:
    path = tmp_path / "t.xml"
    path.write_text('<root BTCPP_format="4">\n  <BehaviorTree ID="T">\n    <Robot/>\n  </BehaviorTree>\n</root>\n')
    return path


def with_world(monkeypatch, create) -> None:
    """Install ``create`` as the only world, named ``w``."""
    point = SimpleNamespace(name="w", load=lambda: create)
    monkeypatch.setattr(runtime.app.world, "entry_points", lambda group: [point])


def test_every_error_class_of_the_project_derives_from_the_root():
    from behaviors.execute_policy.chunk import ChunkError
    from behaviors.execute_policy.config import ConfigError
    from behaviors.poses import FrameError
    from policy.wire import WireError
    from runtime.tree.ports import ConversionError
    from runtime.motion.scene.model import GroupError
    from sim.controllers.admittance import GoalError

    for cls in (ChunkError, ConfigError, FrameError, WireError, ConversionError, GroupError, GoalError, OptionError,
                SetupError):
        assert issubclass(cls, ObjectiveError) and issubclass(cls, ObjectiveRuntimeError), cls
    assert issubclass(InternalError, ObjectiveRuntimeError) and not issubclass(InternalError, ObjectiveError)


def test_a_world_that_refuses_an_option_is_bad_input(registry, tmp_path, monkeypatch, capsys):
    def create(options):
        raise OptionError("option 'image_size' must be a whole number, got 'big'")

    with_world(monkeypatch, create)
    code = main(["run", str(robot_tree(tmp_path)), "--world", "w", "--json"], registry=registry)
    out, err = capsys.readouterr()
    assert code == 2
    assert err == "error: world 'w': option 'image_size' must be a whole number, got 'big'\n"
    assert json.loads(out.splitlines()[-1])["failure_kind"] == "OptionError"


def test_a_bug_in_a_world_is_an_internal_error_never_the_users_mistake(registry, tmp_path, monkeypatch, capsys):
    def create(options):
        return [][0] if options else None  # a bug: IndexError; a ValueError would be one just the same

    def create_value_error(options):
        raise ValueError("could not broadcast input array from shape (3,) into shape (4,)")

    for broken in (create, create_value_error):
        with_world(monkeypatch, broken)
        monkeypatch.chdir(tmp_path)
        code = main(["run", str(robot_tree(tmp_path)), "--world", "w", "--json"], registry=registry)
        out, err = capsys.readouterr()
        summary = json.loads(out.splitlines()[-1])
        assert code == 2 and summary["failure_kind"] == INTERNAL
        assert err.startswith("internal error: an unexpected ") and "Traceback" not in err
        assert err.rstrip().endswith("(a bug: please report it with that file)")
        assert "the full traceback is in build/logs/objective-" in err


def test_a_world_option_that_is_not_a_number_is_bad_input_not_a_crash():
    from sim.world import number_option

    with pytest.raises(OptionError, match=r"^option 'image_size' must be a whole number, got 'big'$"):
        number_option({"image_size": "big"}, "image_size", 224, int)
    assert number_option({"image_size": "64"}, "image_size", 224, int) == 64
    assert number_option({}, "camera_rate_hz", 10.0) == 10.0


def test_a_rejected_chunk_says_which_check_it_failed():
    from behaviors.execute_policy.checks import CheckFailure
    from behaviors.execute_policy.failure import FailureKind

    assert FailureKind.of_limit("velocity") is FailureKind.VELOCITY_LIMIT
    assert FailureKind.of_collision("world") is FailureKind.WORLD_COLLISION
    failure = CheckFailure(FailureKind.ACCELERATION_LIMIT, "densified step 3: joint j acceleration 9 exceeds the limit 5")
    assert f"chunk 6 rejected: {failure}" == "chunk 6 rejected: densified step 3: joint j acceleration 9 exceeds the limit 5"


def test_evaluation_groups_failures_by_their_kind_not_their_text():
    from evaluation.episode import WORKER_LOST, EpisodeRecord, EpisodeStatus
    from evaluation.stats import failure_groups

    def failed(seed: int, reason: str, kind: str | None, node: str | None = "ExecutePolicy") -> EpisodeRecord:
        return EpisodeRecord(seed=seed, status=EpisodeStatus.FAILURE, reason=reason, failing_node=node, failure_kind=kind)

    records = [
        failed(1, "chunk 6 rejected: densified step 3: joint shoulder_lift_joint velocity 3.2 exceeds 3.1", "velocity limit"),
        failed(2, "chunk 9 rejected: densified step 7: joint wrist_1_joint velocity 3.4 exceeds 3.1", "velocity limit"),
        failed(3, "chunk 6 rejected: densified step 3: joint shoulder_lift_joint acceleration 12 exceeds 10", "acceleration limit"),
        failed(4, "cube 0.02 m off", None, "top cube on bottom cube"),
        EpisodeRecord.error(5, "its worker died (signal SIGABRT); 2 attempts, each lost its worker", kind=WORKER_LOST),
    ]
    groups = failure_groups(records)
    assert [(g["failure_kind"], g["reason"], g["seeds"]) for g in groups] == [
        ("velocity limit", "velocity limit", [1, 2]),
        ("worker lost", "worker lost", [5]),
        ("acceleration limit", "acceleration limit", [3]),
        (None, "cube 0.02 m off", [4]),
    ]
    assert groups[0]["example"].startswith("chunk 6 rejected: densified step 3: joint shoulder_lift_joint velocity")


def test_the_report_shows_every_policy_run(tmp_path):
    from recording.report.data import Recording
    from recording.report.html import _summary_table

    runs = [{"node": "policy", "chunks": 1, "steps_executed": 19, "stall_seconds": 0.0, "message": "the policy answered ERROR"},
            {"node": "policy", "chunks": 3, "steps_executed": 60, "stall_seconds": 0.2, "message": "executed 60 steps"}]
    summary = {"status": "FAILURE", "failure_kind": "velocity limit",
               "execute_policy": {"run_count": 2, "chunks": 4, "steps_executed": 79, "runs": runs}}
    table = _summary_table(Recording(tmp_path, summary=summary))
    assert "<th>kind of failure</th><td>velocity limit</td>" in table
    assert "<th>ExecutePolicy runs</th><td>2</td>" in table and "<th>ExecutePolicy chunks</th><td>4</td>" in table
    assert "<th>ExecutePolicy run 1 (policy)</th><td>1 chunks, 19 steps, 0.0 s stalled: the policy answered ERROR</td>" in table


def test_a_missing_policy_service_is_explained_for_the_mode_the_run_is_in():
    from behaviors.execute_policy.startup import policy_hint as hint
    from runtime.io.bus import InProcessBus
    from runtime.io.clock import SimClock

    assert hint(object()) == "start the adapter (`objective adapter`) before running the Objective"  # a ROS 2 graph
    assert hint(InProcessBus(SimClock())) == "in this run the world serves the policy chosen with --policy; services here: none"


def test_an_unknown_controller_the_tree_computes_ends_the_run_as_error(tmp_path):
    from runtime.tree.registry import Registry
    from runtime.app.runner import RunOptions, run_file

    path = tmp_path / "switch.xml"
    path.write_text("""<root BTCPP_format="4"><BehaviorTree ID="Main"><RetryUntilSuccessful num_attempts="3"><Sequence>
      <Script code="name := 'scaled_joint_trajectory_controller'"/>
      <SwitchController activate_controllers="{name}" strictness="STRICT"/>
    </Sequence></RetryUntilSuccessful></BehaviorTree></root>""")
    result = run_file(path, Registry.from_entry_points(), RunOptions(world="kinematic", max_seconds=10.0))
    assert (result.status, result.failure_kind, result.failing_node) == ("ERROR", "SetupError", "SwitchController")
    assert result.reason == (f"{path}:3: SwitchController: unknown controllers: scaled_joint_trajectory_controller (known: "
                             "force_torque_sensor_broadcaster, joint_trajectory_admittance_controller, joint_trajectory_controller, "
                             "robotiq_gripper_controller, velocity_force_controller)")


def test_every_failure_kind_is_one_enum_with_the_summary_strings_evaluations_group_by():
    """A failure's kind is one ``FailureKind`` whether a check failed or something else ended the
    run; its value is the ``failure_kind`` of the summary and of an evaluation's groups."""
    from behaviors.execute_policy.failure import CHECK_KINDS, REJECTED_CHUNK_KINDS, Failure, FailureKind

    checks = ["position limit", "velocity limit", "acceleration limit", "workspace limit", "tool axis limit",
              "linear speed limit", "angular speed limit", "self collision", "world collision"]
    others = ["chunk too short", "malformed chunk", "policy error", "policy timeout", "controller", "gripper",
              "scene changed", "stale observation", "force-torque threshold"]
    assert [kind.value for kind in FailureKind] == checks + others
    assert sorted(kind.value for kind in CHECK_KINDS) == sorted(checks)
    assert REJECTED_CHUNK_KINDS == CHECK_KINDS | {FailureKind.SHORT_CHUNK, FailureKind.MALFORMED_CHUNK}
    assert Failure(FailureKind.WORLD_COLLISION, "x").rejects_chunk and not Failure(FailureKind.CONTROLLER, "x").rejects_chunk
