"""The Objectives the success-under-latency benchmark compares: the same Prepare SubTree
(``Prepare for Policy on JTC`` of ``objectives/stack_cubes_jtc.xml``: the stock
``joint_trajectory_controller``, gripper open, arm at Home), the same policy settings and total
steps, the same stack check (``Check if One Cube Is on Another``, a FAILURE when the blue cube is
not on the green one); only the executor differs. Beside the executor, in a ``Parallel`` that
ends with it, the probe ``CountUnsafeCommands`` counts the unsafe points the controller commanded
(``unsafe_points``).
"""
from __future__ import annotations

import enum
from dataclasses import dataclass


class Executor(enum.Enum):
    """The executors, by the name the benchmark's ``--executors`` takes."""

    RTC = "rtc"  # ExecutePolicy, policy_uses_real_time_chunking="true"
    NO_RTC = "no_rtc"  # ExecutePolicy, policy_uses_real_time_chunking="false"
    SYNC = "sync"  # ExecuteChunksSynchronously
    LEROBOT = "lerobot"  # ExecuteWithLeRobotQueue
    LEROBOT_RTC = "lerobot_rtc"  # ExecuteWithLeRobotRtc
    NEWEST_WINS = "newest_wins"  # ExecuteNewestWinsOnJtc
    JTC_UPSAMPLING = "jtc_upsampling"  # ExecuteOnJtcWithUpsampling

    @property
    def node(self) -> str:
        return {Executor.RTC: "ExecutePolicy", Executor.NO_RTC: "ExecutePolicy", Executor.SYNC: "ExecuteChunksSynchronously",
                Executor.LEROBOT: "ExecuteWithLeRobotQueue", Executor.LEROBOT_RTC: "ExecuteWithLeRobotRtc",
                Executor.NEWEST_WINS: "ExecuteNewestWinsOnJtc",
                Executor.JTC_UPSAMPLING: "ExecuteOnJtcWithUpsampling"}[self]

    @property
    def label(self) -> str:
        return {Executor.RTC: "ExecutePolicy + RTC", Executor.NO_RTC: "ExecutePolicy", Executor.SYNC: "synchronous",
                Executor.LEROBOT: "LeRobot queue", Executor.LEROBOT_RTC: "LeRobot RTC engine",
                Executor.NEWEST_WINS: "newest-wins JTC",
                Executor.JTC_UPSAMPLING: "JTC positions_upsampling"}[self]


@dataclass(frozen=True)
class PolicySettings:
    """The ports every executor gets (``objectives/stack_cubes.xml``'s values by default)."""

    total_action_steps: int = 300
    dt: float = 0.1
    committed_action_steps: int = 20
    policy_tracking_weight: float = 300.0
    policy_call_timeout: float = 10.0


def objective_xml(executor: Executor, settings: PolicySettings = PolicySettings()) -> str:
    rtc = ""
    if executor in (Executor.RTC, Executor.NO_RTC):
        rtc = f'\n          policy_uses_real_time_chunking="{str(executor is Executor.RTC).lower()}"\n          guidance_horizon="18"'
    s = settings
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<!-- Written by benchmarks/executors/objectives.py: executor {executor.value} ({executor.label}). -->
<root BTCPP_format="4" main_tree_to_execute="Stack Cubes ({executor.value})">
  <BehaviorTree ID="Stack Cubes ({executor.value})" _description="Prepare the cell on the JTC, run the policy with {executor.label}, then check the stack">
    <Sequence>
      <SubTree ID="Prepare for Policy on JTC"/>
      <Parallel success_count="1" failure_count="1">
        <{executor.node}
            policy_service_name="/get_action_chunk"
            joint_group_name="manipulator"
            prompt="stack the blue cube on the green cube"
            total_action_steps="{s.total_action_steps}"
            dt="{s.dt}"
            committed_action_steps="{s.committed_action_steps}"
            num_interpolation_points="200"
            goal_path_tolerance="0.3"
            policy_tracking_weight="{s.policy_tracking_weight}"{rtc}
            policy_call_timeout="{s.policy_call_timeout}"
            image_topics="/scene_camera/color;/wrist_camera/color;/overview_camera/color"
            image_names="scene;wrist;overview"
            joint_states_topic="/joint_states"
            controller_action_name="/joint_trajectory_controller/follow_joint_trajectory"
            wrench_topic="/force_torque_sensor_broadcaster/wrench"
            gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd"
            gripper_joint_name="robotiq_85_left_knuckle_joint"
            steps_executed="{{steps_executed}}"
            chunks_received="{{chunks_received}}"
            status_message="{{policy_message}}"/>
        <CountUnsafeCommands joint_group_name="manipulator" gripper_joint_name="robotiq_85_left_knuckle_joint" unsafe_points="{{unsafe_points}}"/>
      </Parallel>
      <SubTree ID="Check if One Cube Is on Another" top_color="blue" bottom_color="green"/>
    </Sequence>
  </BehaviorTree>
</root>
"""
