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

A request may override the ports of the Objective's nodes (``PortOverride``: every node with
that name, checked and converted exactly as the XML's own values are, before anything runs)
and set root blackboard entries (as ``objective run --set``). A bad override is an
``ObjectiveError`` naming the override and what is wrong with it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from .behavior import NodeKind
from .errors import ObjectiveError, did_you_mean
from .loader import LoadedTree, load_tree, parse_document, throwaway_context, top_level_trees
from .registry import Registry


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
    """The node's name (its ``name`` attribute, else its ID); every node so named gets the value."""
    port: str
    value: str


def parse_override(text: str) -> PortOverride:
    """``NODE.PORT=VALUE`` (the node's name may hold dots and spaces; the port is after the last dot)."""
    target, sep, value = text.partition("=")
    node, dot, port = target.rpartition(".")
    if not sep or not dot or not node.strip() or not port.strip():
        raise ValueError(f"expected NODE.PORT=VALUE (e.g. wait.seconds=0.5), got {text!r}")
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


def apply_port_overrides(loaded: LoadedTree, overrides: Iterable[PortOverride]) -> None:
    """Set each override's port on every node of ``loaded`` with that name, as if the XML wrote it."""
    for override in overrides:
        what = f"port override {override.node}.{override.port}={override.value!r}"
        targets = [info for info in loaded.nodes if info.node.name == override.node]
        if not targets:
            names = sorted({info.node.name for info in loaded.nodes})
            hint = did_you_mean(override.node, names)
            raise ObjectiveError(f"{what}: no node named '{override.node}' in '{loaded.tree_id}'{hint} "
                                 f"(nodes: {', '.join(names)})")
        for info in targets:
            if info.kind is NodeKind.SUBTREE:
                raise ObjectiveError(f"{what}: '{override.node}' is a SubTree; set the entry its port remaps "
                                     "with a blackboard override instead")
            values = {k: v for k, v in info.values.items() if k not in ("name", "ID") and not k.startswith("_")}
            values[override.port] = override.value
            node = info.node
            try:
                node.bind(node.context, node.blackboard, values, info.location, info.xml_id)
            except ObjectiveError as err:
                raise ObjectiveError(f"{what}: {err}") from None
            info.values[override.port] = override.value
