"""Pre- and post-conditions on any node: ``_skipIf``, ``_while``, ``_onSuccess`` and friends.

BehaviorTree.CPP v4 lets every node carry scripts (``TreeNode::executeTick``,
``checkPreConditions``, ``checkPostConditions`` and ``haltNode`` in src/tree_node.cpp):

* pre-conditions, checked in this order before the node's own tick, only when the node is idle:
  ``_failureIf`` (true: FAILURE without ticking), ``_successIf`` (true: SUCCESS),
  ``_skipIf`` (true: SKIPPED), ``_while`` (false: SKIPPED). ``_while`` is also checked while the
  node is RUNNING: when it turns false the node is halted and reported SKIPPED. A node that
  finished and was not reset yet (re-ticked by a reactive parent) checks none of them.
* post-conditions, run when the tick completes the node: ``_onSuccess`` or ``_onFailure``, then
  ``_post``; ``_onHalted`` runs when the node is halted while RUNNING.

Why a wrapper: ``attach_conditions`` returns a transparent ``ConditionGuard`` around the node
rather than patching it. The guard works under any parent (our controls, the loader's SubTree, a
plain py_trees tree), leaves the node's own py_trees lifecycle untouched, and a node without
condition attributes is returned as is, so the common case costs nothing. The guard has no
status of its own: ``guard.status`` *is* the wrapped node's status (read and written through), so
a parent that resets or halts the guard resets or halts the node, exactly as BT.CPP does to the
one node that carries the scripts.

SKIPPED: py_trees has no such status. A skipped node keeps its status (INVALID, i.e. idle — BT.CPP
also "preserves the IDLE state if skipped") and sets ``skipped = True`` for that tick; every
control and decorator in ``runtime.tree.controls``/``runtime.tree.decorators`` reads it through
``tick_child``. See ``runtime.tree.controls`` for how each of them treats a skipped child.
"""
from __future__ import annotations

from typing import Any, Iterator, cast

import py_trees

from . import node_info
from .behavior import NodeMixin, Status
from .controls import COMPLETED, SKIPPED, Behaviour, tick_child
from runtime.errors import LoadError, ScriptRunError, SourceLocation
from .script import Script, ScriptError, compile_script, evaluate_condition

PRE_CONDITIONS = ("_failureIf", "_successIf", "_skipIf", "_while")
"""In BT.CPP's order of evaluation (``PreCond``): the first that decides wins."""
POST_CONDITIONS = ("_onHalted", "_onFailure", "_onSuccess", "_post")
CONDITION_ATTRIBUTES = PRE_CONDITIONS + POST_CONDITIONS


def _node_label(node: Behaviour) -> str:
    return f"{node_info.xml_id(node)} '{node.name}'"


def attach_conditions(node: Behaviour, attrs: dict[str, str], location: SourceLocation | None) -> Behaviour:
    """Compile the condition scripts in ``attrs`` and return what goes into the tree.

    ``attrs`` maps attribute names (``_skipIf`` ...) to script source. Returns ``node`` itself
    when there is nothing to attach, else a ``ConditionGuard`` around it. Raises LoadError naming
    the attribute on an unknown attribute or a script that does not parse.
    """
    label = _node_label(node)
    scripts: dict[str, Script] = {}
    for name, source in attrs.items():
        if name not in CONDITION_ATTRIBUTES:
            raise LoadError(
                f"unknown condition attribute '{name}' (known: {', '.join(CONDITION_ATTRIBUTES)})", location, label
            )
        try:
            scripts[name] = compile_script(source)
        except ScriptError as err:
            raise LoadError(f"attribute '{name}': {err}", location, label) from None
    if not scripts:
        return node
    if node_info.blackboard(node) is None:
        raise LoadError("condition attributes need a node bound to a blackboard", location, label)
    return ConditionGuard(node, scripts, location)


class ConditionGuard(py_trees.composites.Composite):
    """Runs a node's pre/post-condition scripts around its tick (BT.CPP ``executeTick``)."""

    transparent = True
    """Marks a wrapper that is not a node of the tree in BT.CPP's sense (see controls.was_active)."""

    def __init__(self, node: Behaviour, scripts: dict[str, Script], location: SourceLocation | None) -> None:
        self.node = node  # before Behaviour.__init__, which writes ``status`` through to the node
        super().__init__(name=node.name, children=[node])
        self.scripts = dict(scripts)
        self.location = location
        self.skipped = False
        self.xml_id = node_info.xml_id(node)
        self.kind = node_info.kind(node)

    # The guard's status and feedback are the node's own.
    @property
    def status(self) -> Status:
        return self.node.status

    @status.setter
    def status(self, value: Status) -> None:
        self.node.status = value

    @property
    def feedback_message(self) -> str:
        return self.node.feedback_message

    @feedback_message.setter
    def feedback_message(self, value: str) -> None:
        self.node.feedback_message = value

    # -- ticking -----------------------------------------------------------------------------
    def tick(self) -> Iterator[Behaviour]:
        self.skipped = False
        decided = self._check_preconditions()
        if decided is None:
            result = yield from tick_child(self.node)
        else:
            result = decided
            if result in COMPLETED:
                self.node.status = result  # the node finishes without its own tick running
        if result in COMPLETED:
            self._post_conditions(result)
        self.skipped = result is SKIPPED
        yield self

    def _check_preconditions(self) -> Status | None:
        """BT.CPP ``checkPreConditions``: a status that replaces the tick, or None to tick."""
        status = self.node.status
        for name in PRE_CONDITIONS:
            script = self.scripts.get(name)
            if script is None:
                continue
            if status is Status.INVALID:
                if self._condition(name, script):
                    if name == "_failureIf":
                        return Status.FAILURE
                    if name == "_successIf":
                        return Status.SUCCESS
                    if name == "_skipIf":
                        return SKIPPED
                elif name == "_while":
                    return SKIPPED
            elif status is Status.RUNNING and name == "_while":
                if not self._condition(name, script):
                    self._halt_node()
                    return SKIPPED
        return None

    def _post_conditions(self, result: Status) -> None:
        """BT.CPP ``checkPostConditions``: _onSuccess or _onFailure, then _post."""
        self._run("_onSuccess" if result is Status.SUCCESS else "_onFailure")
        self._run("_post")

    # -- halting -----------------------------------------------------------------------------
    def stop(self, new_status: Status = Status.INVALID) -> None:
        if new_status is Status.INVALID:
            self._halt_node()
        else:
            self.node.stop(new_status)
        self.iterator = self.tick()

    def _halt_node(self) -> None:
        """BT.CPP ``haltNode``: halt the node, then run ``_onHalted`` (only if it was running)."""
        was_running = self.node.status is Status.RUNNING
        if was_running:
            self.node.stop(Status.INVALID)
        self.node.status = Status.INVALID
        if was_running:
            self._run("_onHalted")

    # -- scripts -----------------------------------------------------------------------------
    def _condition(self, name: str, script: Script) -> bool:
        try:
            return evaluate_condition(script, cast(NodeMixin, self.node).blackboard)  # every built node is one
        except ScriptError as err:
            raise self._run_error(name, script, err) from None

    def _run(self, name: str) -> Any:
        script = self.scripts.get(name)
        if script is None:
            return None
        try:
            return script.evaluate(cast(NodeMixin, self.node).blackboard)
        except ScriptError as err:
            raise self._run_error(name, script, err) from None

    def _run_error(self, name: str, script: Script, err: ScriptError) -> ScriptRunError:
        what = f"attribute '{name}', script {script.source!r}: {err}"
        return ScriptRunError(what, self.location, _node_label(self.node), script.source)


def unwrap(node: Behaviour) -> Behaviour:
    """The node a guard wraps (or ``node`` itself): for displays that show XML nodes."""
    while isinstance(node, ConditionGuard):
        node = node.node
    return node
