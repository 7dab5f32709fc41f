"""The one action-goal lifecycle every goal-sending behavior uses (behaviors/action_goal.py)."""
from __future__ import annotations

from typing import Any

from behaviors.action_goal import Goal, GoalState
from runtime.io import bus


class Future(bus.Future):
    """The bus's own future (done-callbacks included), answered by the test."""

    @property
    def value(self) -> Any:
        return self.result()

    def finish(self, value: Any) -> None:
        self.set_result(value)


class Handle:
    def __init__(self, accepted: bool) -> None:
        self.accepted = accepted
        self.result_future = Future()
        self.cancels = 0

    def get_result_async(self) -> Future:
        return self.result_future

    def cancel_goal_async(self) -> None:
        self.cancels += 1


class Client:
    def __init__(self) -> None:
        self.sent: list[Any] = []
        self.future = Future()

    def send_goal_async(self, message: Any) -> Future:
        self.sent.append(message)
        return self.future


def test_a_goal_is_sent_accepted_and_ends_with_its_outcome():
    client = Client()
    goal = Goal.send(client, "go", 1.5)
    assert (goal.state, goal.sent_at_s, client.sent) == (GoalState.SENT, 1.5, ["go"])
    assert goal.advance() == goal  # no answer yet
    handle = Handle(accepted=True)
    client.future.finish(handle)
    goal = goal.advance()
    assert (goal.state, goal.handle) == (GoalState.PLAYING, handle)
    handle.result_future.finish("outcome")
    goal = goal.advance()
    assert (goal.state, goal.outcome, goal.sent_at_s) == (GoalState.ENDED, "outcome", 1.5)


def test_an_answer_and_a_result_that_came_together_end_the_goal_in_one_step():
    client = Client()
    handle = Handle(accepted=True)
    handle.result_future.finish("outcome")
    client.future.finish(handle)
    assert Goal.send(client, "go").advance().state is GoalState.ENDED


def test_a_refused_goal_is_rejected():
    client = Client()
    client.future.finish(Handle(accepted=False))
    assert Goal.send(client, "go").advance().state is GoalState.REJECTED


def test_cancel_asks_the_server_only_when_it_may_be_playing_the_goal():
    client = Client()
    sent = Goal.send(client, "go")
    handle = Handle(accepted=True)
    client.future.finish(handle)
    assert sent.cancel() == Goal() and handle.cancels == 1  # accepted, not yet read
    assert sent.advance().cancel() == Goal() and handle.cancels == 2  # playing
    refused = Client()
    refused.future.finish(Handle(accepted=False))
    assert Goal.send(refused, "go").cancel() == Goal() and refused.future.value.cancels == 0
    assert Goal().cancel() == Goal()


def test_a_goal_cancelled_on_its_way_is_cancelled_once_the_server_accepts_it():
    # The run ends while a goal has not been answered: if the server accepts it later, it must
    # not play.
    client = Client()
    assert Goal.send(client, "go").cancel() == Goal()
    handle = Handle(accepted=True)
    client.future.finish(handle)
    assert handle.cancels == 1
    refused, lost = Client(), Client()
    Goal.send(refused, "go").cancel()
    refused.future.finish(Handle(accepted=False))
    assert refused.future.value.cancels == 0
    Goal.send(lost, "go").cancel()
    lost.future.set_exception(TimeoutError("the goal never reached the server"))  # nothing to cancel, no error
