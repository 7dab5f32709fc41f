"""Differential test: random trees of every control and decorator, ours vs BehaviorTree.CPP.

A seeded generator builds small trees (controls, decorators, scripted Step/Check leaves with
random status scripts, some nodes carrying ``_skipIf``), ticks each in both engines and compares
statuses, leaf events (start/run/halt/check) and order after every tick. Timer-based nodes are
left out (wall clock in BT.CPP); so are infinite Repeat/Retry loops and skipped conditions of
IfThenElse/WhileDoElse, which are errors (covered by cases/).
"""
from __future__ import annotations

import importlib.util
import random

import pytest

from .harness import Case, run_btcpp, run_ours

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("behaviortreepy") is None, reason="behaviortreepy is not installed"
)

CONTROLS = ["Sequence", "AsyncSequence", "SequenceWithMemory", "Fallback", "AsyncFallback", "ReactiveSequence", "ReactiveFallback", "Parallel", "ParallelAll"]
DECORATORS = [
    "Inverter", "ForceSuccess", "ForceFailure", "KeepRunningUntilFailure", "RetryUntilSuccessful", "Repeat", "RunOnce",
    "Precondition",
]


class _Gen:
    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)
        self.leaves = 0

    def leaf(self, condition_ok: bool = True) -> str:
        self.leaves += 1
        letters = "".join(self.rng.choice("RSF") for _ in range(self.rng.randint(1, 4)))
        if condition_ok and self.rng.random() < 0.3:
            letters = letters.replace("R", "S")
            return f'<Check name="c{self.leaves}:{letters}"/>'
        return f'<Step name="a{self.leaves}:{letters}"/>'

    def skip_attr(self) -> str:
        roll = self.rng.random()
        return ' _skipIf="true"' if roll < 0.08 else (' _skipIf="false"' if roll < 0.12 else "")

    def node(self, depth: int, may_skip: bool = True) -> str:
        skip = self.skip_attr() if may_skip else ""
        if depth <= 0 or self.rng.random() < 0.3:
            tag = self.leaf()
            return tag.replace("/>", f"{skip}/>")
        kind = self.rng.random()
        if kind < 0.5:
            name = self.rng.choice(CONTROLS)
            count = self.rng.randint(1, 3)
            attrs = ""
            if name == "Parallel":
                attrs = f' success_count="{self.rng.choice([-1, -2, 1, 2])}" failure_count="{self.rng.choice([-1, 1, 2])}"'
                count = 3
            if name == "ParallelAll":
                attrs = f' max_failures="{self.rng.choice([-1, 1, 2])}"'
                count = 2
            children = "".join(self.node(depth - 1) for _ in range(count))
            return f"<{name}{attrs}{skip}>{children}</{name}>"
        if kind < 0.65:
            name = self.rng.choice(["IfThenElse", "WhileDoElse"])
            children = self.node(depth - 1, may_skip=False) + "".join(
                self.node(depth - 1) for _ in range(self.rng.randint(1, 2))
            )
            return f"<{name}{skip}>{children}</{name}>"
        name = self.rng.choice(DECORATORS)
        attrs = ""
        if name == "RetryUntilSuccessful":
            attrs = f' num_attempts="{self.rng.randint(1, 3)}"'
        elif name == "Repeat":
            attrs = f' num_cycles="{self.rng.randint(1, 3)}"'
        elif name == "RunOnce":
            attrs = f' then_skip="{self.rng.choice(["true", "false"])}"'
        elif name == "Precondition":  # a constant condition: see dialect.md on halting a Precondition
            otherwise = self.rng.choice(["SUCCESS", "FAILURE", "SKIPPED", "RUNNING"])
            attrs = f' if="{self.rng.choice(["true", "false"])}" else="{otherwise}"'
        return f"<{name}{attrs}{skip}>{self.node(depth - 1)}</{name}>"


def random_case(seed: int) -> Case:
    gen = _Gen(seed)
    body = gen.node(depth=3, may_skip=False)
    xml = f'<root BTCPP_format="4"><BehaviorTree ID="Main">{body}</BehaviorTree></root>'
    return Case(name=f"random_{seed}", xml=xml, ticks=8)


@pytest.mark.parametrize("chunk", range(4))
def test_random_trees_match_behaviortree_cpp(chunk: int) -> None:
    for seed in range(chunk * 100, (chunk + 1) * 100):
        case = random_case(seed)
        theirs = run_btcpp(case)
        ours = run_ours(case)
        context = f"seed {seed}: {case.xml}"
        assert ours.statuses == theirs.statuses, f"{context}\nBT.CPP error: {theirs.error}\nours: {ours.error}"
        assert ours.events == theirs.events, context
