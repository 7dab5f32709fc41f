"""Text views for the CLI: the loaded tree (``objective show``) and the progress line of a run."""
from __future__ import annotations

import time
from typing import TextIO

import py_trees

from runtime.tree import node_info
from runtime.tree.behavior import NodeMixin, SummarisesRun
from runtime.tree.controls import Visit
from runtime.tree.loader import CONDITION_ATTRIBUTES, LoadedTree
from runtime.tree.subtree import SubTree
from .observer import RunObserver
from .terminal import printable


def _quote(value: str) -> str:
    return f'"{value}"' if (not value or any(c in value for c in ' ;"')) else value


def describe_node(node: py_trees.behaviour.Behaviour, tree: LoadedTree) -> str:
    """One line: ``Kind ID "name"  port=value ...  (file:line)``."""
    info = tree.info(node)
    if isinstance(node, SubTree):
        parts = [f"SubTree {node.tree_id}"]
        if node.name != node.tree_id:
            parts.append(f'"{node.name}"')
        ports = [f"{k}={{{v}}}" for k, v in sorted(node.remapping.items())]
        ports += [f"{k}={_quote(v)}" for k, v in sorted(node.literals.items())]
        if node.autoremap:
            ports.append("_autoremap=true")
        parts.extend(ports)
    elif isinstance(node, NodeMixin) and node_info.has_bindings(node):
        parts = [f"{type(node).kind.value} {node.xml_id}"]
        if node.name != node.xml_id:
            parts.append(f'"{node.name}"')
        written = info.values if info is not None else {}
        for name, binding in node.bindings.items():
            if name not in written:
                continue  # defaults are listed by `objective behaviors`
            value = f"{{{binding.key}}}" if binding.key is not None else _quote(written[name])
            parts.append(f"{name}={value}")
        parts.extend(f"{k}={_quote(written[k])}" for k in CONDITION_ATTRIBUTES if k in written)
    else:
        parts = [f"{type(node).__name__} \"{node.name}\""]
    if info is not None:
        parts.append(f"({info.location})")
    return "  ".join(parts)


def tree_text(tree: LoadedTree) -> str:
    """The tree as indented text, one node per line."""
    lines = [f"BehaviorTree {tree.tree_id}"]

    def visit(node: py_trees.behaviour.Behaviour, depth: int) -> None:
        if node_info.is_transparent(node) and len(node.children) == 1:
            visit(node.children[0], depth)  # a condition guard: its node's line shows the scripts
            return
        lines.append("  " * depth + describe_node(node, tree))
        for child in node.children:
            visit(child, depth + 1)

    visit(tree.root, 1)
    return "\n".join(lines)


class ProgressLine(RunObserver):
    """A single self-overwriting status line on a terminal, at most ``rate_hz`` updates per second:
    the clock, the ticks, the policy's progress and the running node.

    The CLI only creates it when the stream is a TTY, so logs and pipes stay quiet.
    """

    def __init__(self, stream: TextIO, rate_hz: float = 10.0) -> None:
        self.stream = stream
        self.min_interval = 1.0 / rate_hz
        self._last = -float("inf")
        self._width = 0
        self._root: py_trees.behaviour.Behaviour | None = None
        self._ticks = 0
        self._reporters: list[SummarisesRun] = []

    def started(self, loaded: LoadedTree) -> None:
        """The policy's progress comes from the nodes with ``run_summary()`` (ExecutePolicy), asked at display time."""
        self._root, self._ticks = loaded.root, 0
        self._reporters = [n for n in loaded.root.iterate() if isinstance(n, SummarisesRun)]

    def ticked(self, now_s: float, visited: list[Visit]) -> None:
        self._ticks += 1
        now = time.monotonic()  # pacing the display itself, not behavior time
        if now - self._last < self.min_interval:
            return
        self._last = now
        tip = self._root.tip() if self._root is not None else None
        self.show(now_s, self._ticks, tip.name if tip is not None else "")

    def policy_text(self) -> str:
        """``steps 120  chunks 6  latency 0.012/0.020 s  stalls 0.00 s`` of the policy run, if one started."""
        for node in self._reporters:
            data = (node.run_summary() or {}).get("execute_policy") or {}
            if "chunks" in data:
                return (f"steps {data['steps_executed']}  chunks {data['chunks']}  "
                        f"latency p50/max {data['latency_p50_s']:.3f}/{data['latency_max_s']:.3f} s  "
                        f"stalls {data['stall_seconds']:.2f} s")
        return ""

    def show(self, sim_seconds: float, ticks: int, running: str) -> None:
        """Write the line now."""
        policy = self.policy_text()
        text = f"t={sim_seconds:8.2f}s  ticks={ticks:7d}  " + (f"{policy}  " if policy else "") + f"running: {printable(running)}"
        text = text[:160]
        self.stream.write("\r" + text.ljust(self._width))
        self.stream.flush()
        self._width = len(text)

    def clear(self) -> None:
        if self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
            self._width = 0
