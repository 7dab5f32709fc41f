"""The heap of a paced loop (``runtime.io.heap``): what set-up made is frozen and garbage is collected
between ticks; and the ROS 2 type support a run's clients need is loaded before its first tick."""
from __future__ import annotations

import gc
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.io.heap import MIDDLE_EVERY, OLDEST_EVERY, PacedHeap
from runtime.tree.loader import load_tree
from runtime.tree.registry import Registry
from runtime.app.observer import RunObserver
from runtime.app.runner import RunOptions, make_context, run_tree
from runtime.app.world_check import declared_interfaces

WAIT_XML = """<root BTCPP_format="4"><BehaviorTree ID="Main"><Sleep msec="50"/></BehaviorTree></root>"""


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


@pytest.fixture
def collector_on():
    was_enabled = gc.isenabled()
    gc.enable()
    yield
    gc.unfreeze()
    (gc.enable if was_enabled else gc.disable)()


def test_inside_the_heap_is_frozen_and_collected_only_between_ticks(collector_on):
    kept = [object() for _ in range(10)]
    with PacedHeap() as heap:
        assert gc.get_freeze_count() > len(kept)
        assert not any(o is kept[0] for o in gc.get_objects())  # no collection walks it
        assert not gc.isenabled()  # nothing collects inside a tick
        collected: list[int] = []
        gc.callbacks.append(lambda phase, info: phase == "start" and collected.append(info["generation"]))
        try:
            for _ in range(OLDEST_EVERY):
                heap.between_ticks()
        finally:
            gc.callbacks.pop()
    assert collected.count(2) == 1 and collected.count(1) == OLDEST_EVERY // MIDDLE_EVERY - 1
    assert collected.count(0) == OLDEST_EVERY - OLDEST_EVERY // MIDDLE_EVERY
    assert gc.get_freeze_count() == 0 and gc.isenabled()  # given back
    del kept


def test_nothing_changes_when_disabled_or_when_the_caller_turned_the_collector_off(collector_on):
    with PacedHeap(enabled=False) as heap:
        heap.between_ticks()
        assert gc.get_freeze_count() == 0 and gc.isenabled()
    gc.disable()
    with PacedHeap() as heap:
        heap.between_ticks()
        assert gc.get_freeze_count() == 0
    assert not gc.isenabled()  # the caller's choice is kept


class FreezeWatcher(RunObserver):
    def __init__(self) -> None:
        self.counts: list[int] = []

    def ticked(self, now_s, visited) -> None:
        self.counts.append(gc.get_freeze_count() if not gc.isenabled() else 0)


@pytest.mark.parametrize("realtime", [True, False])
def test_a_paced_run_ticks_on_a_frozen_heap_and_a_simulated_one_does_not(registry, collector_on, realtime):
    options = RunOptions(realtime=realtime, max_seconds=5.0)
    context = make_context(options)
    watcher = FreezeWatcher()
    result = run_tree(load_tree(WAIT_XML, registry, context), context, options, [watcher])

    assert result.status == "SUCCESS", result.reason
    assert len(watcher.counts) >= 2  # the tick that starts the Sleep and the one that sees it end
    if realtime:
        assert min(watcher.counts) > 10_000  # everything set-up made, the interpreter's own included
    else:
        assert max(watcher.counts) == 0
    assert gc.get_freeze_count() == 0  # given back when the run ended


def test_the_interfaces_a_tree_declares_are_each_listed_once(registry):
    from control_msgs.action import FollowJointTrajectory, GripperCommand
    from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance
    from moveit_pro_ml_msgs.srv import GetActionChunk

    context = make_context(RunOptions())
    loaded = load_tree(Path(__file__).parent.parent / "objectives" / "stack_cubes.xml", registry, context)
    interfaces = declared_interfaces(loaded.root.iterate())
    assert len(interfaces) == len(set(interfaces))
    assert {GetActionChunk, FollowJointTrajectoryWithAdmittance, FollowJointTrajectory, GripperCommand} <= set(interfaces)


@pytest.mark.ros
def test_type_support_is_loaded_and_the_named_clients_exist_before_the_first_tick():
    """In a fresh interpreter: nothing has loaded GripperCommand's C type support until
    ``prepare_links`` does, and the clients it made are the ones behaviors then get."""
    code = (
        "import os, random\n"
        "os.environ['ROS_DOMAIN_ID'] = str(random.randint(100, 199)); os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'\n"
        "from control_msgs.action import GripperCommand\n"
        "from std_srvs.srv import Trigger\n"
        "from runtime.io.clock import WallClock\n"
        "from runtime.io.ros.bus import RosBus\n"
        "from runtime.io.ros.run import prepare_links\n"
        "assert GripperCommand._TYPE_SUPPORT is None\n"
        "with RosBus(WallClock(), node_name='prepare', serves=False) as bus:\n"
        "    prepare_links(bus, [GripperCommand], services=[('/t', Trigger)], actions=[('/g', (GripperCommand,))])\n"
        "    assert GripperCommand._TYPE_SUPPORT is not None\n"
        "    assert [c.name for c in bus._clients] == ['/t'] and [c.name for c in bus._action_clients] == ['/g']\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_the_services_and_actions_a_tree_names_are_listed_once_with_their_types(registry):
    from control_msgs.action import FollowJointTrajectory, GripperCommand
    from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance
    from moveit_pro_ml_msgs.srv import GetActionChunk

    from runtime.tree.ports import NameKind
    from runtime.app.world_check import named_links

    context = make_context(RunOptions())
    loaded = load_tree(Path(__file__).parent.parent / "objectives" / "stack_cubes.xml", registry, context)
    links = {(name, kind): types for name, kind, types in named_links(loaded.nodes)}
    assert len(links) == len(named_links(loaded.nodes))
    assert links[("/get_action_chunk", NameKind.SERVICE)] == (GetActionChunk,)
    assert links[("/robotiq_gripper_controller/gripper_cmd", NameKind.ACTION)] == (GripperCommand,)
    assert set(links[("/joint_trajectory_admittance_controller/follow_joint_trajectory", NameKind.ACTION)]) == {
        FollowJointTrajectoryWithAdmittance, FollowJointTrajectory}


@pytest.mark.ros
def test_a_ros_node_keeps_one_client_per_name_and_type(monkeypatch):
    import random

    from control_msgs.action import GripperCommand
    from std_srvs.srv import Trigger

    from runtime.io.clock import WallClock
    from runtime.io.ros.bus import RosBus

    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.randint(100, 199)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    with RosBus(WallClock(), node_name="clients", serves=False) as bus:
        assert bus.create_client("/a", Trigger) is bus.create_client("/a", Trigger)
        assert bus.create_client("/a", Trigger) is not bus.create_client("/b", Trigger)
        assert bus.create_action_client("/g", GripperCommand) is bus.create_action_client("/g", GripperCommand)
