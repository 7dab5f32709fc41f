"""BT.CPP's script leaves: ``Script``, ``ScriptCondition`` and ``SetBlackboard``.

The ``code`` of a script node is compiled when the node is bound (at load time), so a syntax
error stops the load with the file, line, node and column; ticking only evaluates.
A script that fails while running (``=`` to an undeclared entry, a missing entry, a type
mismatch) raises ``ScriptRunError``: BT.CPP throws there, so the tick is aborted and the run ends
as an error (exit 2, ``ERROR`` in ``--json``, running nodes halted) instead of a FAILURE that a
Fallback would quietly take its next branch on.
"""
from __future__ import annotations

from typing import Any, ClassVar

from . import script as scripting
from .behavior import Behavior, Condition, PortBinding, Status
from runtime.errors import LoadError, ScriptRunError, SourceLocation
from .ports import InOutPort, InputPort, PortInfo, PortType


def compile_at_load(
    source: str,
    location: SourceLocation | None,
    node: str,
    where: str = "port 'code'",
) -> scripting.Script:
    """Compile ``source`` or raise LoadError("file:line: Node: port 'code': <why> at column N ...").

    Also for the loader's script attributes (``_skipIf``, ``_post``...): pass ``where`` to name
    the attribute in the message.
    """
    try:
        return scripting.compile_script(source)
    except scripting.ScriptError as err:
        raise LoadError(f"{where}: {err} in script {source!r}", location, node) from None


class _CompiledCode:
    """Compiles the literal ``code`` port in ``bind`` so errors surface at load time."""

    script: scripting.Script
    # The node's own (NodeMixin's and py_trees' Behaviour's), which every class that mixes this in is.
    bindings: dict[str, PortBinding]
    location: SourceLocation | None
    xml_id: str
    name: str

    def run_error(self, err: scripting.ScriptError) -> ScriptRunError:
        source = self.script.source
        label = f"{self.xml_id} '{self.name}'"
        return ScriptRunError(f"script {source!r}: {err}", self.location, label, source)

    def check_literals(self) -> None:
        binding = self.bindings["code"]
        if binding.key is not None:
            raise LoadError(
                f"port 'code' must be the script itself, not a blackboard reference '{{{binding.key}}}'",
                self.location,
                self.xml_id,
            )
        self.script = compile_at_load(binding.literal, self.location, self.xml_id)


_CODE = InputPort("code", PortType.STRING, description="The script: statements separated by ';'")


class Script(_CompiledCode, Behavior):
    """Runs a script (e.g. ``count := count + 1``) and succeeds; a failing script is a run error."""

    ports: ClassVar[tuple[PortInfo, ...]] = (_CODE,)
    description = "Run a script against the blackboard; SUCCESS (a script that cannot be evaluated stops the run)."

    def update(self) -> Status:
        try:
            self.script.evaluate(self.blackboard)
        except scripting.ScriptError as err:
            raise self.run_error(err) from None
        return Status.SUCCESS


class ScriptCondition(_CompiledCode, Condition):
    """SUCCESS when the script's value is true, FAILURE when false; a failing script is a run error."""

    ports: ClassVar[tuple[PortInfo, ...]] = (
        InputPort("code", PortType.STRING, description="An expression that is true or false"),
    )
    description = "Evaluate a script as a condition: SUCCESS if true, FAILURE if false."

    def update(self) -> Status:
        try:
            holds = scripting.evaluate_condition(self.script, self.blackboard)
        except scripting.ScriptError as err:
            raise self.run_error(err) from None
        if holds:
            return Status.SUCCESS
        return self.fail(f"{self.script.source!r} is false")


class SetBlackboard(Behavior):
    """Writes ``value`` into the entry named by ``output_key``, as BT.CPP's SetBlackboard.

    ``output_key="target"`` names the entry (BT.CPP's spelling); ``output_key="{target}"`` is
    accepted too and writes ``target`` (BT.CPP would read the key's name out of ``target``).
    ``value="{src}"`` copies the entry ``src`` with its type; a literal is a string, converted to
    the type the destination already holds (an integer entry takes ``"7"`` as 7).
    """

    ports: ClassVar[tuple[PortInfo, ...]] = (
        InputPort("value", PortType.ANY, description="Value to write, or '{key}' to copy another entry"),
        InOutPort(
            "output_key", PortType.STRING, description="Name of the blackboard entry where the value is written"
        ),
    )
    description = "Write a value (or a copy of another entry) into a blackboard entry."

    def update(self) -> Status:
        output = self.bindings["output_key"]
        key = output.key if output.key is not None else str(output.literal).strip()
        if not key:
            return self.fail("port 'output_key' is empty")
        source = self.bindings["value"]
        value: Any
        current = self.blackboard.get(key) if self.blackboard.has(key) else None
        if source.key is not None:
            if not self.blackboard.has(source.key):  # BT.CPP throws: the entry does not exist
                raise self.run_error(f"port 'value' reads blackboard entry '{source.key}', which does not exist")
            value = self.blackboard.get(source.key)
            if value is None:  # declared but never written: BT.CPP returns FAILURE
                return self.fail(f"port 'value' reads blackboard entry '{source.key}', which is empty")
            if current is not None and type(value) is not type(current):
                value = self._coerce(key, current, value)
        else:
            value = self._coerce(key, current, source.literal)
        self.blackboard.set(key, value)
        return Status.SUCCESS

    def _coerce(self, key: str, current: Any, value: Any) -> Any:
        try:
            return scripting.coerce_for_entry(key, current, value)
        except scripting.ScriptError as err:
            raise self.run_error(str(err)) from None

    def run_error(self, what: str) -> ScriptRunError:
        value = self.bindings["value"]
        shown = f"{{{value.key}}}" if value.key is not None else str(value.literal)
        return ScriptRunError(f"value {shown!r}: {what}", self.location, f"{self.xml_id} '{self.name}'", shown)


class UnsetBlackboard(Behavior):
    """BT.CPP ``UnsetBlackboardNode``: removes an entry of this blackboard, then SUCCESS.

    Like BT.CPP's ``Blackboard::unset`` it removes only an entry stored on the node's own
    blackboard: in a SubTree, a remapped or auto-remapped entry of the caller is left alone.
    """

    ports: ClassVar[tuple[PortInfo, ...]] = (InputPort("key", PortType.STRING, description="Key of the entry to remove"),)
    description = "Remove a blackboard entry (nothing happens if it does not exist); SUCCESS."

    def update(self) -> Status:
        self.blackboard.unset(self.get_input("key"))
        return Status.SUCCESS


NODES = (Script, ScriptCondition, SetBlackboard, UnsetBlackboard)
