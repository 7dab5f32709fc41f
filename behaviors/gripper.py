"""MoveGripperAction: one GripperCommand goal (0.0 is open, as on the Robotiq)."""
from __future__ import annotations

from control_msgs.action import GripperCommand

from runtime.tree.behavior import Behavior, Status
from runtime.io.bus import STATUS_SUCCEEDED
from runtime.errors import SetupError
from runtime.tree.ports import InputPort, NameKind, Names, PortType, Range

from .action_goal import Goal, GoalState
from .waiting import Deadline, when_ready


def gripper_command(position: float, max_effort_n: float) -> GripperCommand.Goal:
    """A GripperCommand goal: move the gripper joint to ``position`` with at most ``max_effort_n``."""
    goal = GripperCommand.Goal()
    goal.command.position = float(position)
    goal.command.max_effort = float(max_effort_n)
    return goal


class MoveGripperAction(Behavior):
    """Send the gripper to ``position`` and wait. SUCCESS when it gets there, or when it stalls
    on an object (a closed grasp); FAILURE when the action aborts or the timeout passes."""

    needs_world = True
    description = "Move the gripper to a position (0.0 = open) and wait until it gets there or stalls on an object."
    ports = (
        InputPort("gripper_command_action_name", PortType.STRING, "/robotiq_gripper_controller/gripper_cmd", "GripperCommand action.",
                  names=Names(NameKind.ACTION, GripperCommand)),
        InputPort("position", PortType.FLOAT, description="Target of the gripper joint (0.0 = open, 0.8 = closed on the 2F-85).", valid=Range(-10.0, 10.0, "rad or m")),
        InputPort("max_effort", PortType.FLOAT, 100.0, "Largest force (N) the fingers may apply.", valid=Range(0.0, 10_000.0, "N")),
        InputPort("timeout", PortType.FLOAT, 5.0, "Seconds to wait for the server and the motion.", valid=Range(0.0, 3600.0, "s", min_open=True)),
    )

    goal = Goal()

    def initialise(self) -> None:
        self.action = self.get_input("gripper_command_action_name")
        self.client = self.context.bus.create_action_client(self.action, GripperCommand)
        self.deadline = Deadline(self, self.get_input("timeout"))
        self.goal = Goal()

    def update(self) -> Status:
        if self.goal.state is GoalState.NONE:
            ready = when_ready(self.client.server_is_ready, self.deadline, f"gripper action '{self.action}'")
            if ready is not True:
                return self.fail(ready) if isinstance(ready, str) else Status.RUNNING
            self.goal = Goal.send(self.client, gripper_command(self.get_input("position"), self.get_input("max_effort")))
        self.goal = self.goal.advance()
        if self.goal.state is GoalState.REJECTED:
            raise SetupError(f"gripper action '{self.action}' rejected the goal: is the gripper controller active, "
                             "and the position within its range?")
        if self.goal.state is not GoalState.ENDED:
            return self._waiting()
        outcome = self.goal.outcome
        result = outcome.result
        if outcome.status != STATUS_SUCCEEDED:
            return self.fail(f"gripper action '{self.action}' did not succeed (goal status {outcome.status}, position {result.position:.3f})")
        if result.reached_goal or result.stalled:
            self.feedback_message = f"gripper at {result.position:.3f}" + (" (stalled on an object)" if result.stalled and not result.reached_goal else "")
            return Status.SUCCESS
        return self.fail(f"gripper stopped at {result.position:.3f} without reaching {self.get_input('position'):.3f}")

    def _waiting(self) -> Status:
        if self.deadline.expired:
            self.goal = self.goal.cancel()
            return self.fail(f"gripper did not finish within {self.deadline.seconds:g} s")
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            self.goal = self.goal.cancel()


NODES = (MoveGripperAction,)
