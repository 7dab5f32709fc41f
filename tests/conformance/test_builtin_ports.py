"""Every BT.CPP 4.x built-in node is registered, with BT.CPP's ports: names, directions, defaults.

The table is read off BehaviorTree.CPP 4.10's ``providedPorts()`` (``BehaviorTreeFactory``'s
constructor lists the built-ins; 4.8 has the same ones without TryCatch). A default of None
means BT.CPP declares none. ``SubTree`` is built by the loader, not registered as a node, and
``_autoremap`` is its only port (tests/test_loader.py).
"""
from __future__ import annotations

import pytest

from runtime.tree import builtin
from runtime.tree.ports import Direction
from runtime.tree.registry import Registry

IN, OUT, INOUT = "input", "output", "inout"
LOOP = {"queue": (INOUT, None), "if_empty": (IN, "SUCCESS"), "value": (OUT, None)}
UPDATED = {"entry": (IN, None)}


def switch(cases: int) -> dict[str, tuple[str, str | None]]:
    return {"variable": (IN, None), **{f"case_{i}": (IN, None) for i in range(1, cases + 1)}}


BTCPP_BUILTINS: dict[str, dict[str, tuple[str, str | None]]] = {
    "Fallback": {}, "AsyncFallback": {}, "Sequence": {}, "AsyncSequence": {}, "SequenceWithMemory": {},
    "Parallel": {"success_count": (IN, "-1"), "failure_count": (IN, "1")},
    "ParallelAll": {"max_failures": (IN, "1")},
    "ReactiveSequence": {}, "ReactiveFallback": {}, "IfThenElse": {}, "WhileDoElse": {},
    "TryCatch": {"catch_on_halt": (IN, "false")},
    "Inverter": {},
    "RetryUntilSuccessful": {"num_attempts": (IN, None)},
    "KeepRunningUntilFailure": {},
    "Repeat": {"num_cycles": (IN, None)},
    "Timeout": {"msec": (IN, None)},
    "Delay": {"delay_msec": (IN, None)},
    "RunOnce": {"then_skip": (IN, "true")},
    "ForceSuccess": {}, "ForceFailure": {}, "AlwaysSuccess": {}, "AlwaysFailure": {},
    "Script": {"code": (IN, None)},
    "ScriptCondition": {"code": (IN, None)},
    "SetBlackboard": {"value": (IN, None), "output_key": (INOUT, None)},
    "Sleep": {"msec": (IN, None)},
    "UnsetBlackboard": {"key": (IN, None)},
    "Precondition": {"if": (IN, None), "else": (IN, "FAILURE")},
    **{f"Switch{n}": switch(n) for n in range(2, 7)},
    "LoopInt": LOOP, "LoopBool": LOOP, "LoopDouble": LOOP, "LoopString": LOOP,
    "WasEntryUpdated": UPDATED, "SkipUnlessUpdated": UPDATED, "WaitValueUpdate": UPDATED,
}
KINDS = {
    "Decorator": {
        "Inverter", "RetryUntilSuccessful", "KeepRunningUntilFailure", "Repeat", "Timeout", "Delay", "RunOnce",
        "ForceSuccess", "ForceFailure", "Precondition", "LoopInt", "LoopBool", "LoopDouble", "LoopString",
        "SkipUnlessUpdated", "WaitValueUpdate",
    },
    "Condition": {"ScriptCondition"},
}


@pytest.fixture(scope="module")
def registry() -> Registry:
    registry = Registry()
    builtin.register(registry)
    return registry


def _direction(direction: Direction) -> str:
    return {Direction.INPUT: IN, Direction.OUTPUT: OUT, Direction.INOUT: INOUT}[direction]


@pytest.mark.parametrize("node_id", sorted(BTCPP_BUILTINS))
def test_builtin_is_registered_with_btcpp_ports(registry, node_id) -> None:
    spec = registry.get(node_id)
    assert spec is not None, f"BT.CPP built-in '{node_id}' is not registered"
    ours = {p.name: (_direction(p.direction), p.describe_default() if p.has_default else None) for p in spec.cls.ports}
    assert ours == BTCPP_BUILTINS[node_id]
    kind = next((k for k, ids in KINDS.items() if node_id in ids), None)
    if kind is not None:
        assert spec.kind.value == kind
    elif spec.kind.value != "Action":
        assert spec.kind.value == "Control"


def test_the_builtins_are_the_ones_behaviortree_cpp_lists(registry) -> None:
    """behaviortreepy (4.8.2) builds every one of them but TryCatch (4.10) from the same XML."""
    import behaviortreepy as bt  # a test dependency: missing, the test fails
    leaves_and_decorators = [n for n in BTCPP_BUILTINS if n not in ("TryCatch",)]
    for node_id in leaves_and_decorators:
        spec = registry.get(node_id)
        assert spec is not None
        kind = spec.kind.value
        attrs = " ".join(f'{name}="{value}"' for name, value in _sample_ports(node_id).items())
        if kind == "Decorator":
            body = f"<{node_id} {attrs}><AlwaysSuccess/></{node_id}>"
        elif kind == "Control":
            count = int(node_id[-1]) + 1 if node_id.startswith("Switch") else 2
            body = f"<{node_id} {attrs}>{'<AlwaysSuccess/>' * count}</{node_id}>"
        else:
            body = f"<{node_id} {attrs}/>"
        xml = f'<root BTCPP_format="4"><BehaviorTree ID="M">{body}</BehaviorTree></root>'
        bt.BehaviorTreeFactory().create_tree_from_text(xml)  # raises on an unknown node or port


def _sample_ports(node_id: str) -> dict[str, str]:
    samples = {
        "RetryUntilSuccessful": {"num_attempts": "2"}, "Repeat": {"num_cycles": "2"}, "Timeout": {"msec": "10"},
        "Delay": {"delay_msec": "10"}, "Script": {"code": "a := 1"}, "ScriptCondition": {"code": "true"},
        "SetBlackboard": {"value": "1", "output_key": "a"}, "Sleep": {"msec": "1"}, "UnsetBlackboard": {"key": "a"},
        "Precondition": {"if": "true", "else": "SKIPPED"}, "WasEntryUpdated": {"entry": "{a}"},
        "SkipUnlessUpdated": {"entry": "{a}"}, "WaitValueUpdate": {"entry": "{a}"},
    }
    if node_id.startswith("Loop"):
        return {"queue": "1;0", "value": "{v}", "if_empty": "FAILURE"}
    if node_id.startswith("Switch"):
        return {"variable": "{v}", "case_1": "1"}
    return samples.get(node_id, {})
