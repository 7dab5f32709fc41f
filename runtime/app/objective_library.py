"""The Objective server's library: the Objectives of a directory by name, and a run's overrides.

Every ``*.xml`` file under the directory (subdirectories too) is one Objective, named by the
BehaviorTree it runs (``main_tree_to_execute``, else the file's only tree no other uses), as
MoveIt Pro names Objectives. Its description is that tree's ``_description``; its ports are the
TreeNodesModel entry of that tree, if the file has one: root blackboard entries, which a run
starts with set to their defaults. SubTrees are found as ``objective run`` finds them: in the
file, in the directory, in the ``search_paths`` after it (the shipped ``objectives/`` last). A
file that cannot be read, or whose tree does not load (an unknown node, a missing required
port, an undefined SubTree), is listed with its error, so a typo shows where it is rather than an
Objective silently missing or failing only when it is run.

A request may set the ports the Objective declares as its own (its TreeNodesModel entry), as
MoveIt Pro's Objective server does: ``PortOverride`` (port by name) and blackboard overrides
(root entries, as ``objective run --set``) alike reach only those ports, which are root
blackboard entries. A port of a node inside the Objective is never reachable from a request (a
client could otherwise widen a collision rule or rewrite a Script); an override of an
undeclared port is an ``ObjectiveError`` naming it and the ports the Objective declares.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from runtime.errors import ObjectiveError, did_you_mean
from runtime.tree.loader import load_tree, parse_document, throwaway_context, top_level_trees
from runtime.tree.registry import Registry


@dataclass(frozen=True)
class ObjectivePort:
    name: str
    direction: str
    type: str
    default: str


@dataclass(frozen=True)
class Objective:
    name: str
    file: Path
    relative: str
    """The file, relative to the library directory."""
    description: str = ""
    ports: list[ObjectivePort] = field(default_factory=list)
    error: str = ""
    """Why the file cannot be run (empty when it can)."""

    def defaults(self) -> dict[str, str]:
        """The root blackboard entries a run starts with: each input port's literal model default."""
        return {p.name: p.default for p in self.ports
                if p.direction != "output_port" and p.default and not p.default.startswith("{")}


@dataclass(frozen=True)
class PortOverride:
    node: str
    """The Objective's name, or empty: nothing else (an override reaches only the Objective's ports)."""
    port: str
    value: str


def parse_override(text: str) -> PortOverride:
    """``PORT=VALUE``, a port the Objective declares, or ``OBJECTIVE.PORT=VALUE`` (the Objective's
    name may hold dots and spaces; the port is after the last dot)."""
    target, sep, value = text.partition("=")
    node, _, port = target.rpartition(".")
    if not sep or not port.strip():
        raise ValueError(f"expected PORT=VALUE (e.g. seconds=0.5), got {text!r}")
    return PortOverride(node.strip(), port.strip(), value)


def read_objective(file: Path, directory: Path, registry: Registry | None = None,
                   search_paths: Iterable[Path] = ()) -> Objective:
    """The Objective ``file`` holds, or an entry carrying its error. With ``registry`` its tree is
    also built (nothing runs), so a load error is the entry's error too."""
    relative = str(file.relative_to(directory))
    try:
        doc = parse_document(file, [directory, *search_paths])
    except ObjectiveError as err:
        return Objective(file.stem, file, relative, error=str(err))
    tops = top_level_trees(doc)
    name = doc.main_tree or (tops[0] if len(tops) == 1 else None)
    if name is None or name not in doc.trees:
        why = (f"main_tree_to_execute names '{name}', which the file does not define" if name
               else f"several BehaviorTrees ({', '.join(tops)}) and no main_tree_to_execute")
        return Objective(file.stem, file, relative, error=f"{relative}: {why}")
    model = doc.models.get(name)
    ports = [ObjectivePort(p.name, p.direction, p.type, p.default or "") for p in model.ports.values()] if model else []
    description = doc.trees[name].element.get("_description", "")
    error = ""
    if registry is not None:
        try:
            load_tree(file, registry, throwaway_context(), name, search_paths, directory)
        except ObjectiveError as err:
            error = str(err)
    return Objective(name, file, relative, description, ports, error)


class Library:
    """The Objectives of ``directory``, read again on every ``objectives()`` (files change).

    SubTrees are searched in ``directory``, then in ``search_paths``; with ``registry`` every
    Objective's tree is built when the library is read (see ``read_objective``)."""

    def __init__(self, directory: Path, registry: Registry | None = None, search_paths: Iterable[Path] = ()) -> None:
        if not directory.is_dir():
            raise ObjectiveError(f"the Objective library '{directory}' is not a directory")
        self.directory, self.registry, self.search_paths = directory, registry, list(search_paths)

    def objectives(self) -> list[Objective]:
        files = sorted(p for p in self.directory.rglob("*.xml") if p.is_file())
        return [read_objective(file, self.directory, self.registry, self.search_paths) for file in files]

    def find(self, name: str) -> Objective:
        """The Objective called ``name``; ObjectiveError when there is none, several, or it is broken."""
        everything = self.objectives()
        found = [o for o in everything if o.name == name]
        if not found:
            known = ", ".join(sorted({o.name for o in everything if not o.error})) or "none"
            raise ObjectiveError(f"no Objective named '{name}' in {self.directory} (Objectives: {known})")
        if len(found) > 1:
            raise ObjectiveError(f"several Objectives are named '{name}': {', '.join(o.relative for o in found)}")
        if found[0].error:
            raise ObjectiveError(f"Objective '{name}' cannot run: {found[0].error}")
        return found[0]


def override_entries(objective: Objective, ports: Iterable[PortOverride], blackboard: dict[str, str]) -> dict[str, str]:
    """The root blackboard entries a request's overrides set. Each must name an input port
    ``objective`` declares (its TreeNodesModel entry); anything else is an ObjectiveError naming
    the override and the declared ports."""
    declared = {p.name for p in objective.ports if p.direction != "output_port"}
    listed = f"its ports: {', '.join(sorted(declared))}" if declared else "it declares none"
    entries: dict[str, str] = {}

    def admit(what: str, port: str, value: str) -> None:
        if port not in declared:
            raise ObjectiveError(f"{what}: '{port}' is not a port Objective '{objective.name}' declares"
                                 f"{did_you_mean(port, sorted(declared))} ({listed}); overrides reach only the Objective's own ports")
        entries[port] = value

    for key, value in blackboard.items():
        admit(f"blackboard override {key}={value!r}", key, value)
    for override in ports:
        what = f"port override {override.node + '.' if override.node else ''}{override.port}={override.value!r}"
        if override.node not in ("", objective.name):
            raise ObjectiveError(f"{what}: '{override.node}' is not Objective '{objective.name}'; overrides reach only "
                                 f"the Objective's own ports, never a node's inside it ({listed})")
        admit(what, override.port, override.value)
    return entries
