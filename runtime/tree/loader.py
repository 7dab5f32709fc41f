"""BehaviorTree.CPP v4 XML -> a tree of py_trees nodes, with every error pointing at the source.

What is read:

* ``<root BTCPP_format="4" main_tree_to_execute="Main">`` holding any number of
  ``<BehaviorTree ID="...">`` (each with exactly one root node), an optional ``<TreeNodesModel>``
  and ``<include path="other.xml"/>`` (relative to the including file, and only inside that
  file's directory, the objectives directory or a search path).
* Nodes in both syntaxes: ``<Action ID="Wait" seconds="1"/>`` (also ``Condition``, ``Control``,
  ``Decorator``) and the compact ``<Wait seconds="1"/>``. ``name`` is the display name;
  ``_description``, ``_favorite``, ``_collapsed``, ``_uid``, ``_fullpath`` are Groot2 metadata and
  ignored; ``_skipIf``, ``_successIf``, ``_failureIf``, ``_while``, ``_onSuccess``,
  ``_onFailure``, ``_post``, ``_onHalted`` are scripts handed to ``runtime.tree.conditions``.
  Every other attribute is a port, checked and converted by the node class (``NodeMixin.bind``).
* ``<SubTree ID="Pick" target="{goal}" speed="0.5" _autoremap="true"/>``: the tree ``Pick`` on
  a child blackboard (``{key}`` remaps a port to the caller's entry, a literal is stored
  locally, ``_autoremap`` shares every other entry). SubTree IDs resolve from the file itself
  (and its includes), then every ``*.xml`` in the objectives directory, then each search path
  in order; the first place that defines the ID wins, and two files of the same place defining
  it is an error (only when it is used). Recursion between SubTrees is a load-time error.
* ``TreeNodesModel`` port defaults. For a SubTree they apply when the instance leaves the port
  unset (a ``{key}`` default remaps, anything else is a literal), and a SubTree that has a model
  accepts only the ports its model declares. For a registered node the class declaration is
  the reference: a model default fills a port only when the class declares it required.

Parsing is safe: no DTDs, no entities (a DOCTYPE is refused outright), no network, bounded
file size, nesting depth, attribute length and number of nodes after SubTree expansion.
"""
from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import py_trees
from lxml import etree

from . import node_info
from .behavior import NodeKind, NodeMixin, RunContext
from .blackboard import Blackboard
from .crash import LOAD_STOPPED, describe_crash, write_traceback
from runtime.errors import E, LoadError, ObjectiveError, ObjectiveRuntimeError, PortError, SourceLocation, did_you_mean
from .ports import ConversionError, Direction, PortType, convert, parse_reference
from .registry import Registry
from .subtree import SubTree

log = logging.getLogger("objective.loader")

MAX_FILE_BYTES = 5 * 1024 * 1024
MAX_DEPTH = 200
MAX_ATTRIBUTE_CHARS = 65536
MAX_ATTRIBUTES = 1000
"""Attributes per element: lxml reads an element's attribute values in time quadratic in their count."""
MAX_NODES = 20000
MAX_TREE_DEPTH = 150
"""Nodes on the longest path from the root to a leaf once SubTrees are expanded (a SubTree node
counts as one): ticking one level takes a few Python frames, so deeper trees would stop on
Python's recursion limit in the middle of a run."""
"""Bound on nodes after SubTree expansion: nested SubTrees used several times grow exponentially."""

METADATA_ATTRIBUTES = frozenset({"_description", "_favorite", "_collapsed", "_uid", "_fullpath", "_external"})
CONDITION_ATTRIBUTES = (
    "_skipIf", "_successIf", "_failureIf", "_while", "_onSuccess", "_onFailure", "_post", "_onHalted",
)
EXPLICIT_TAGS = {
    "Action": (NodeKind.ACTION, NodeKind.CONDITION),
    "Condition": (NodeKind.ACTION, NodeKind.CONDITION),
    "Control": (NodeKind.CONTROL,),
    "Decorator": (NodeKind.DECORATOR,),
}
MODEL_TAGS = frozenset({"Action", "Condition", "Control", "Decorator", "SubTree"})
PORT_TAGS = frozenset({"input_port", "output_port", "inout_port"})


def default_objectives_dir() -> Path:
    """The project's shipped Objectives: ``<repo>/objectives`` next to the ``runtime`` package."""
    import runtime

    return Path(runtime.__file__).resolve().parent.parent / "objectives"


def display_path(path: Path) -> str:
    """A path as errors show it: relative to the working directory when it is inside it."""
    try:
        return os.path.relpath(path) if Path(path).resolve().is_relative_to(Path.cwd()) else str(path)
    except ValueError:
        return str(path)


# ------------------------------------------------------------------------------------------------
# Parsed documents
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ModelPort:
    name: str
    direction: str
    default: str | None
    type: str
    location: SourceLocation


@dataclass
class NodeModel:
    """One ``TreeNodesModel`` entry."""

    tag: str
    id: str
    ports: dict[str, ModelPort]
    location: SourceLocation


@dataclass
class TreeDef:
    id: str
    element: Any
    document: Document
    location: SourceLocation


@dataclass
class Document:
    """One XML file with its includes: its trees, models and main tree."""

    display: str
    base_dir: Path
    path: Path | None = None
    main_tree: str | None = None
    trees: dict[str, TreeDef] = field(default_factory=dict)
    own_tree_ids: list[str] = field(default_factory=list)
    """Trees written in this file itself, in order (not those of included files)."""
    models: dict[str, NodeModel] = field(default_factory=dict)
    unnamed_trees: int = 0
    files: list[Path] = field(default_factory=list)
    """Every file read into this document: its own, then its includes'."""
    """``<BehaviorTree>`` elements without an ID so far; BT.CPP names them BehaviorTree_0, _1, ..."""

    @property
    def key(self) -> str:
        return str(self.path) if self.path else self.display


def _refuse_doctype(data: bytes, display: str) -> LoadError:
    idx = data.find(b"<!DOCTYPE")
    if idx < 0:
        idx = max(data.find(b"<!ENTITY"), 0)
    line = data[:idx].count(b"\n") + 1
    return LoadError(
        "DOCTYPE and entity declarations are not allowed in Objectives (refused for safety; "
        "remove the <!DOCTYPE ...> block)",
        SourceLocation(display, line),
    )


def parse_xml(data: bytes, display: str) -> Any:
    """Parse untrusted XML: no DTD, no entities, no network, bounded size and depth.

    Returns the root element; raises LoadError with the file and line on anything refused.
    """
    if len(data) > MAX_FILE_BYTES:
        raise LoadError(f"file is {len(data)} bytes; Objectives are limited to {MAX_FILE_BYTES} bytes", SourceLocation(display))
    parser = etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        remove_comments=True,
        remove_pis=True,
    )
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as err:
        if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
            raise _refuse_doctype(data, display) from None
        raise LoadError(f"not well-formed XML: {err.msg}", SourceLocation(display, err.lineno or 0)) from None
    docinfo = root.getroottree().docinfo
    if docinfo.doctype or docinfo.internalDTD is not None or b"<!ENTITY" in data:
        raise _refuse_doctype(data, display)
    _check_bounds(root, display)
    _use_start_lines(root, data)
    return root


_MARKUP = re.compile(rb"<!--.*?-->|<!\[CDATA\[.*?\]\]>|<\?.*?\?>|<([A-Za-z_][\w.:-]*)", re.DOTALL)


def _use_start_lines(root: Any, data: bytes) -> None:
    """Make ``sourceline`` the line where each start tag begins (libxml2 gives the line it ends on).

    Start tags appear in the text in document order, so they pair up with ``root.iter()``;
    comments, CDATA and processing instructions are stepped over. If anything does not pair up
    (an unusual encoding), libxml2's lines are kept.
    """
    starts = (m for m in _MARKUP.finditer(data) if m.group(1) is not None)
    fixes = []
    line, counted = 1, 0  # newlines are counted once, from the previous tag on (linear in the file)
    for element, match in zip(root.iter(), starts):
        if match.group(1).decode("utf-8", "replace") != element.tag:
            return
        line += data.count(b"\n", counted, match.start())
        counted = match.start()
        fixes.append((element, line))
    for element, line in fixes:
        element.sourceline = line


def _check_bounds(root: Any, display: str) -> None:
    stack = [(root, 1)]
    while stack:
        element, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise LoadError(f"elements nest deeper than {MAX_DEPTH} levels", SourceLocation(display, element.sourceline or 0))
        if not isinstance(element.tag, str):
            raise LoadError("entity references are not allowed", SourceLocation(display, element.sourceline or 0))
        if len(element.attrib) > MAX_ATTRIBUTES:
            raise LoadError(
                f"<{element.tag}> has {len(element.attrib)} attributes (limit {MAX_ATTRIBUTES})",
                SourceLocation(display, element.sourceline or 0),
            )
        for name, value in element.attrib.items():
            if len(value) > MAX_ATTRIBUTE_CHARS:
                raise LoadError(
                    f"attribute '{name}' is {len(value)} characters long (limit {MAX_ATTRIBUTE_CHARS})",
                    SourceLocation(display, element.sourceline or 0),
                )
        stack.extend((child, depth + 1) for child in element)


def _elements(element: Any) -> list[Any]:
    return [c for c in element if isinstance(c.tag, str)]


def _child_ids_problem(cls: type[NodeMixin], children: list[Any]) -> str | None:
    """A control node's own rule on which nodes its children are (``check_child_ids``, given their
    node IDs: the tag, or ``ID`` in the explicit form ``<Control ID="X">``), or None."""
    check = getattr(cls, "check_child_ids", None)
    if check is None:
        return None
    problem: str | None = check([str(child.get("ID", "")) if child.tag in EXPLICIT_TAGS else str(child.tag) for child in children])
    return problem


def _read_file(path: Path, display: str) -> bytes:
    try:
        size = path.stat().st_size
    except OSError as err:
        raise LoadError(f"cannot read file: {err.strerror}", SourceLocation(display)) from None
    if size > MAX_FILE_BYTES:
        raise LoadError(f"file is {size} bytes; Objectives are limited to {MAX_FILE_BYTES} bytes", SourceLocation(display))
    if not path.is_file():
        raise LoadError("not a file", SourceLocation(display))
    return path.read_bytes()


def parse_document(
    source: Path | str,
    include_dirs: Iterable[Path] = (),
    *,
    _seen: set[Path] | None = None,
    _into: Document | None = None,
) -> Document:
    """Read one Objective file (a path, or XML text starting with '<') with its includes."""
    if isinstance(source, str) and source.lstrip().startswith("<"):
        path, display, base_dir = None, "<string>", Path.cwd()
        data = source.encode("utf-8")
    else:
        path = Path(source).resolve()
        display, base_dir = display_path(Path(source)), path.parent
        data = _read_file(path, display)
    root = parse_xml(data, display)
    loc = SourceLocation(display, root.sourceline or 0)
    if root.tag != "root":
        raise LoadError(f"the top element must be <root BTCPP_format=\"4\">, got <{root.tag}>", loc)
    fmt = root.get("BTCPP_format")
    if fmt is None:
        log.warning("%s: <root> has no BTCPP_format; reading it as BehaviorTree.CPP v4", loc)
    elif fmt.strip() != "4":
        raise LoadError(f"BTCPP_format=\"{fmt}\" is not supported: this runtime reads BehaviorTree.CPP v4 XML", loc)

    doc = _into or Document(display=display, base_dir=base_dir, path=path, main_tree=root.get("main_tree_to_execute"))
    seen = _seen if _seen is not None else set()
    if path is not None:
        seen.add(path)
        doc.files.append(path)
    own = _into is None
    for element in _elements(root):
        eloc = SourceLocation(display, element.sourceline or 0)
        if element.tag == "BehaviorTree":
            tree_id = element.get("ID")
            if tree_id is None:
                tree_id = f"BehaviorTree_{doc.unnamed_trees}"
                doc.unnamed_trees += 1
            elif not tree_id.strip():
                raise LoadError("<BehaviorTree> has an empty ID", eloc)
            if tree_id in doc.trees:
                raise LoadError(f"BehaviorTree '{tree_id}' is defined twice (first at {doc.trees[tree_id].location})", eloc)
            doc.trees[tree_id] = TreeDef(tree_id, element, doc, eloc)
            if own:
                doc.own_tree_ids.append(tree_id)
        elif element.tag == "TreeNodesModel":
            for model_el in _elements(element):
                model = _parse_model(model_el, display)
                if model is not None:
                    doc.models.setdefault(model.id, model)
        elif element.tag == "include":
            target = _include_target(element, base_dir, include_dirs, eloc)
            if target not in seen:
                parse_document(target, include_dirs, _seen=seen, _into=doc)
        else:
            raise LoadError(
                f"unexpected element <{element.tag}> under <root> (expected BehaviorTree, TreeNodesModel or include)", eloc
            )
    return doc


def _include_target(element: Any, base_dir: Path, include_dirs: Iterable[Path], loc: SourceLocation) -> Path:
    if element.get("ros_pkg"):
        raise LoadError("<include ros_pkg=...> is not supported: use a path relative to this file", loc)
    rel = element.get("path")
    if not rel:
        raise LoadError("<include> needs a path attribute", loc)
    target: Path = (base_dir / rel).resolve()
    allowed = [base_dir.resolve(), *(Path(d).resolve() for d in include_dirs)]
    if not any(target.is_relative_to(d) for d in allowed):
        raise LoadError(
            f"include '{rel}' is outside the allowed directories ({', '.join(display_path(d) for d in allowed)})", loc
        )
    if not target.is_file():
        raise LoadError(f"include '{rel}' not found (looked for {display_path(target)})", loc)
    return target


def _parse_model(element: Any, display: str) -> NodeModel | None:
    loc = SourceLocation(display, element.sourceline or 0)
    if element.tag not in MODEL_TAGS:
        return None  # Groot2 metadata we do not use
    node_id = element.get("ID")
    if not node_id:
        raise LoadError(f"TreeNodesModel <{element.tag}> needs an ID attribute", loc)
    ports: dict[str, ModelPort] = {}
    for port_el in _elements(element):
        if port_el.tag not in PORT_TAGS:
            continue
        ploc = SourceLocation(display, port_el.sourceline or 0)
        name = port_el.get("name")
        if not name:
            raise LoadError(f"<{port_el.tag}> needs a name attribute", ploc, node_id)
        ports[name] = ModelPort(name, port_el.tag, port_el.get("default"), port_el.get("type", ""), ploc)
    return NodeModel(element.tag, node_id, ports, loc)


# ------------------------------------------------------------------------------------------------
# The library of SubTrees: objectives directory, then search paths
# ------------------------------------------------------------------------------------------------
class Library:
    """BehaviorTrees of other files, read lazily the first time a SubTree is not found locally.

    ``places`` are searched in order; each is a directory of ``*.xml`` files. A file that fails
    to parse is skipped (its error is reported if a SubTree cannot be found).
    """

    def __init__(self, places: Iterable[Path], skip: Iterable[Path] = ()) -> None:
        self.places = [Path(p) for p in places]
        self._skip = {Path(p).resolve() for p in skip}
        self._docs: list[list[Document]] | None = None
        self.broken: list[str] = []

    def _load(self) -> list[list[Document]]:
        if self._docs is None:
            self._docs = []
            for place in self.places:
                docs: list[Document] = []
                for path in sorted(place.glob("*.xml")) if place.is_dir() else []:
                    if path.resolve() in self._skip:
                        continue
                    try:
                        docs.append(parse_document(path, self.places))
                    except ObjectiveError as err:
                        self.broken.append(str(err))
                self._docs.append(docs)
        return self._docs

    def find(self, tree_id: str, loc: SourceLocation) -> TreeDef | None:
        for docs in self._load():
            found = [d.trees[tree_id] for d in docs if tree_id in d.trees]
            if len(found) > 1:
                where = " and ".join(str(t.location) for t in found)
                raise LoadError(f"SubTree '{tree_id}' is defined in several files: {where}", loc, tree_id)
            if found:
                return found[0]
        return None

    def tree_ids(self) -> set[str]:
        return {tid for docs in self._load() for d in docs for tid in d.trees}

    def describe(self) -> str:
        return ", ".join(f"{display_path(p)}/*.xml" for p in self.places) or "no library directories"


# ------------------------------------------------------------------------------------------------
# Building the tree
# ------------------------------------------------------------------------------------------------
@dataclass
class LoadedNode:
    """A node of the loaded tree with where it came from (for `objective show` and messages)."""

    node: py_trees.behaviour.Behaviour
    xml_id: str
    kind: NodeKind
    location: SourceLocation
    values: dict[str, str]
    """The port attributes as written (SubTrees: the remapping and literal ports)."""
    callers: tuple[tuple[SourceLocation, str], ...] = ()
    """The SubTree calls this node is inside, outermost first: (where the call is written, the SubTree's ID)."""

    def error(self, error: E) -> E:
        """``error``, raised by this node, placed at it: its ``file:line: Node:`` (if it has none
        yet), preceded by the line of each SubTree call it is inside."""
        if error.location is None:
            label = self.xml_id if self.node.name == self.xml_id else f"{self.xml_id} '{self.node.name}'"
            error.at(self.location, label)
        for caller, subtree in reversed(self.callers):
            error.inside_subtree(caller, subtree)
        return error


@dataclass
class LoadedTree:
    root: py_trees.behaviour.Behaviour
    blackboard: Blackboard
    tree_id: str
    file: Path | None
    nodes: list[LoadedNode]
    files: tuple[Path, ...] = ()
    """Every file the tree was built from: its own, its includes, and each file (with its
    includes) of the library whose trees it uses as SubTrees."""

    def __post_init__(self) -> None:
        self._index = {id(loaded.node): loaded for loaded in self.nodes}

    def info(self, node: py_trees.behaviour.Behaviour) -> LoadedNode | None:
        """Where ``node`` came from (None for wrappers the loader did not write, e.g. condition guards)."""
        return self._index.get(id(node))


def _types_fit(entry: PortType, port: PortType) -> bool:
    """Whether a port of type ``port`` may use an entry of type ``entry`` (see ``_check_entry_types``)."""
    if PortType.ANY in (entry, port) or entry in (port, PortType.STRING):
        return True
    vectors = (entry.value.startswith("std::vector<"), port.value.startswith("std::vector<"))
    return PortType.ANY_LIST in (entry, port) and all(vectors)


def _parse_bool_attr(value: str, name: str, loc: SourceLocation, node: str) -> bool:
    lowered = value.strip().lower()
    if lowered in ("true", "1"):
        return True
    if lowered in ("false", "0"):
        return False
    raise LoadError(f"{name} expects true or false, got {value!r}", loc, node)


@dataclass(frozen=True)
class _EntryType:
    """The type a blackboard entry got from the first port wired to it (BT.CPP's rule)."""

    type: PortType
    location: SourceLocation
    node: str
    port: str


class _Builder:
    """Builds a tree from its XML. With ``collect``, an error in a node is kept in ``errors`` and
    the build goes on with the next node (the broken node is left out), so that every error of a
    file is found; otherwise the first error is raised."""

    def __init__(self, registry: Registry, context: RunContext, library: Library, collect: bool = False) -> None:
        self.registry = registry
        self.context = context
        self.library = library
        self.nodes: list[LoadedNode] = []
        self.collect = collect
        self.errors: list[ObjectiveRuntimeError] = []
        self.unbuilt: list[LoadedNode] = []
        """With ``collect``: nodes whose ports bound but whose port combination was refused
        (``check_literals``), left out of the tree; the world check still reads their names."""
        self.calls: list[tuple[SourceLocation, str]] = []
        """The SubTree calls being built, outermost first."""
        self.entry_types: dict[tuple[int, str], _EntryType] = {}
        self.documents: dict[int, Document] = {}
        """The documents whose trees were built (by id)."""

    # -- resolution ---
    def resolve(self, tree_id: str, doc: Document, loc: SourceLocation) -> TreeDef:
        if tree_id in doc.trees:
            return doc.trees[tree_id]
        found = self.library.find(tree_id, loc)
        if found is not None:
            return found
        searched = f"{doc.display}, then {self.library.describe()}"
        hint = did_you_mean(tree_id, set(doc.trees) | self.library.tree_ids())
        broken = f" (unreadable library files: {'; '.join(self.library.broken)})" if self.library.broken else ""
        raise LoadError(f"undefined SubTree '{tree_id}' (searched {searched}){hint}{broken}", loc, tree_id)

    def model(self, node_id: str, *docs: Document) -> NodeModel | None:
        for doc in docs:
            if node_id in doc.models:
                return doc.models[node_id]
        return None

    # -- construction ---
    def build_tree(self, tree: TreeDef, blackboard: Blackboard, stack: list[tuple[str, str]], depth: int = 0) -> py_trees.behaviour.Behaviour:
        self.documents.setdefault(id(tree.document), tree.document)
        children = _elements(tree.element)
        if len(children) != 1:
            raise LoadError(f"a BehaviorTree has exactly one root node, got {len(children)}", tree.location, tree.id)
        return self.build_node(children[0], tree.document, tree.location.file, blackboard, stack, depth)

    def build_node(
        self, element: Any, doc: Document, file: str, blackboard: Blackboard, stack: list[tuple[str, str]], depth: int = 0
    ) -> py_trees.behaviour.Behaviour:
        """Build ``element`` (written in ``file``, part of ``doc``, with ``depth`` ancestors) and its children."""
        loc = SourceLocation(file, element.sourceline or 0)
        tag = element.tag
        if len(self.nodes) >= MAX_NODES:
            raise LoadError(f"the tree has more than {MAX_NODES} nodes after expanding SubTrees", loc, str(tag))
        if depth >= MAX_TREE_DEPTH:
            trees = [tid for _, tid in stack]
            chain = " -> ".join(trees if len(trees) <= 6 else [*trees[:3], "...", *trees[-3:]])
            raise LoadError(f"the tree nests more than {MAX_TREE_DEPTH} nodes deep after expanding SubTrees "
                            f"({len(trees)} trees deep: {chain})", loc, str(tag))
        if tag == "SubTree":
            return self.build_subtree(element, doc, blackboard, stack, loc, depth)
        attrs = dict(element.attrib)
        if tag in EXPLICIT_TAGS:
            node_id = attrs.pop("ID", None)
            if not node_id:
                raise LoadError(f"<{tag}> needs an ID attribute naming the node", loc, tag)
        else:
            node_id = tag
            attrs.pop("ID", None)
        spec = self.registry.get(node_id)
        if spec is None:
            hint = did_you_mean(node_id, [s.id for s in self.registry.specs()])
            if node_id in doc.trees or (not hint and self.library.find(node_id, loc) is not None):
                hint = f"; '{node_id}' is a BehaviorTree: use <SubTree ID=\"{node_id}\"/>"
            error = LoadError(f"unknown node '{node_id}'{hint or ' (objective behaviors lists the registered nodes)'}", loc, node_id)
            raise self._look_into(element, doc, file, blackboard, stack, error, depth)
        cls = spec.cls
        if tag in EXPLICIT_TAGS and cls.kind not in EXPLICIT_TAGS[tag]:
            raise LoadError(f"'{node_id}' is a {cls.kind.value} node, not a{'n' if tag[0] in 'AE' else ''} {tag}", loc, node_id)

        name = attrs.pop("name", None) or node_id
        conditions, values = self._split_attributes(attrs, loc, node_id)
        model = self.model(node_id, doc)
        if model is not None:
            self._apply_model_defaults(cls, model, values, node_id)

        # The registry's classes are NodeMixin and py_trees Behaviour at once (no intersection type).
        make: Any = cls
        node: Any = None
        try:
            node = make(name)
            node.bind(self.context, blackboard, values, loc, node_id)
        except ObjectiveError as err:
            if self.collect and node_info.has_bindings(node):
                self.unbuilt.append(LoadedNode(node, node_id, cls.kind, loc, dict(element.attrib), tuple(self.calls)))
            raise self._look_into(element, doc, file, blackboard, stack, err, depth) from None
        except ObjectiveRuntimeError:
            raise
        except Exception as err:  # a bug in the node's class: one paragraph, the traceback in a file
            raise describe_crash(err, None, write_traceback(err, None), loc, LOAD_STOPPED, node_id) from None
        self._check_entry_types(node, blackboard, loc, node_id)
        record = LoadedNode(node, node_id, cls.kind, loc, dict(element.attrib), tuple(self.calls))
        self.nodes.append(record)

        children = _elements(element)
        problem = self._child_count_problem(cls, len(children)) or _child_ids_problem(cls, children)
        if problem:
            raise LoadError(problem, loc, node_id)
        for child_el in children:
            child = self._build_child(child_el, doc, file, blackboard, stack, depth + 1)
            if child is not None:
                node.add_child(child)
        return self._with_conditions(node, conditions, loc, node_id)

    def _look_into(self, element: Any, doc: Document, file: str, blackboard: Blackboard, stack: list[tuple[str, str]],
                   error: E, depth: int) -> E:
        """``error`` of a node that cannot be built; with ``collect``, its children are built for
        their errors only, which the error carries (``also``) to be reported after its own."""
        if self.collect:
            first = len(self.errors)
            for child_el in _elements(element):
                self._build_child(child_el, doc, file, blackboard, stack, depth + 1)
            error.also = (*error.also, *self.errors[first:])
            del self.errors[first:]
        return error

    def _build_child(
        self, element: Any, doc: Document, file: str, blackboard: Blackboard, stack: list[tuple[str, str]], depth: int
    ) -> py_trees.behaviour.Behaviour | None:
        """``build_node``; with ``collect``, an error is kept and the child left out (None)."""
        try:
            return self.build_node(element, doc, file, blackboard, stack, depth)
        except ObjectiveError as err:
            if not self.collect:
                raise
            self.errors.extend([err, *err.also])
            return None

    def _check_entry_types(self, node: Any, blackboard: Blackboard, loc: SourceLocation, node_id: str) -> None:
        """BT.CPP's rule for ports wired to one blackboard entry: the first port gives the entry its
        type; a later port of another type is refused unless either is untyped (``AnyTypeAllowed``),
        the entry's type is a string (converted when read), or one is ``std::vector<BT::Any>`` and
        the other a vector (MoveIt Pro's vector nodes are templates, one per element type)."""
        for port, binding in node.bindings.items():
            if binding.key is None:
                continue
            owner, key = blackboard.owner(binding.key)
            slot = (id(owner), key)
            first = self.entry_types.get(slot)
            if first is None:
                self.entry_types[slot] = _EntryType(binding.info.type, loc, node_id, port)
                continue
            if _types_fit(first.type, binding.info.type):
                continue
            port_type = binding.info.type
            raise PortError(
                f"port '{port}' ({port_type.value}) is wired to blackboard entry '{{{binding.key}}}', whose type is "
                f"{first.type.value} (port '{first.port}' of {first.node} at {first.location}): BehaviorTree.CPP "
                "refuses one entry with two types (use another entry, or ports of one type)",
                loc, node_id,
            )

    def build_subtree(
        self, element: Any, doc: Document, blackboard: Blackboard, stack: list[tuple[str, str]], loc: SourceLocation, depth: int
    ) -> py_trees.behaviour.Behaviour:
        attrs = dict(element.attrib)
        tree_id = attrs.pop("ID", None)
        if not tree_id:
            raise LoadError("<SubTree> needs an ID attribute naming the BehaviorTree to run", loc, "SubTree")
        name = attrs.pop("name", None) or tree_id
        autoremap = _parse_bool_attr(attrs.pop("_autoremap", "false"), "_autoremap", loc, tree_id)
        if _elements(element):
            raise LoadError("a SubTree node takes no children (its tree is defined by <BehaviorTree ID>)", loc, tree_id)
        conditions, ports = self._split_attributes(attrs, loc, tree_id)

        tree = self.resolve(tree_id, doc, loc)
        key = (tree.document.key, tree_id)
        if key in stack:
            cycle = [tid for _, tid in stack[stack.index(key):]] + [tree_id]
            raise LoadError(f"recursive SubTree: {' -> '.join(cycle)}", loc, tree_id)

        model = self.model(tree_id, tree.document, doc)
        if model is not None:
            unknown = sorted(set(ports) - set(model.ports))
            if unknown:
                known = ", ".join(sorted(model.ports)) or "none"
                hint = did_you_mean(unknown[0], model.ports)
                raise PortError(f"unknown port '{unknown[0]}'{hint} (ports: {known}; model at {model.location})", loc, tree_id)
            for declared in model.ports.values():
                if declared.name not in ports and declared.default is not None:
                    ports[declared.name] = declared.default

        remapping: dict[str, str] = {}
        literals: dict[str, str] = {}
        for port, value in ports.items():
            try:
                ref = parse_reference(value, port)
            except ValueError as err:
                raise PortError(f"port '{port}': {err}", loc, tree_id) from None
            if ref is not None:
                remapping[port] = ref
            else:
                literals[port] = value
        child_bb = Blackboard(blackboard, remapping, autoremap)
        for port, value in literals.items():
            child_bb.set_local(port, value)
            self.entry_types[(id(child_bb), port)] = _EntryType(PortType.STRING, loc, tree_id, port)

        node = SubTree(name)
        node.bind(self.context, blackboard, {}, loc, tree_id)
        node.tree_id = tree_id
        node.child_blackboard = child_bb
        node.remapping, node.literals, node.autoremap = remapping, literals, autoremap
        self.nodes.append(LoadedNode(node, tree_id, NodeKind.SUBTREE, loc, dict(ports), tuple(self.calls)))
        first_error = len(self.errors)
        self.calls.append((loc, tree_id))
        try:
            node.add_child(self.build_tree(tree, child_bb, [*stack, key], depth + 1))
        except ObjectiveError as err:
            for each in (err, *err.also):
                each.inside_subtree(loc, tree_id)
            raise
        finally:
            self.calls.pop()
            for kept in self.errors[first_error:]:
                kept.inside_subtree(loc, tree_id)
        return self._with_conditions(node, conditions, loc, tree_id)

    # -- helpers ---
    @staticmethod
    def _split_attributes(attrs: dict[str, str], loc: SourceLocation, node_id: str) -> tuple[dict[str, str], dict[str, str]]:
        """(condition scripts, ports); metadata dropped; unknown ``_`` attributes refused."""
        conditions: dict[str, str] = {}
        ports: dict[str, str] = {}
        for attr, value in attrs.items():
            if attr in METADATA_ATTRIBUTES:
                continue
            if attr in CONDITION_ATTRIBUTES:
                conditions[attr] = value
            elif attr.startswith("_"):
                extra = " (BehaviorTree.CPP v3 syntax: use _autoremap=\"true\" on <SubTree>)" if attr == "__shared_blackboard" else ""
                hint = did_you_mean(attr, [*CONDITION_ATTRIBUTES, *METADATA_ATTRIBUTES, "_autoremap"])
                raise LoadError(f"unknown attribute '{attr}'{extra or hint}", loc, node_id)
            else:
                ports[attr] = value
        return conditions, ports

    @staticmethod
    def _apply_model_defaults(cls: type[NodeMixin], model: NodeModel, values: dict[str, str], node_id: str) -> None:
        infos = cls.port_info()
        for port in model.ports.values():
            info = infos.get(port.name)
            if info is None or not info.required or port.name in values or port.default is None:
                continue
            try:
                if parse_reference(port.default, port.name) is None:
                    convert(port.default, info.type)
            except (ValueError, ConversionError) as err:
                raise PortError(f"TreeNodesModel default of port '{port.name}' {err}", port.location, node_id) from None
            values[port.name] = port.default

    @staticmethod
    def _child_count_problem(cls: type[NodeMixin], count: int) -> str | None:
        check = getattr(cls, "check_children", None)
        if check is not None:
            problem: str | None = check(count)
            return problem
        if cls.kind in (NodeKind.ACTION, NodeKind.CONDITION):
            return None if count == 0 else f"a {cls.kind.value} is a leaf and takes no children, got {count}"
        if cls.kind is NodeKind.DECORATOR:
            return None if count == 1 else f"a Decorator takes exactly one child, got {count}"
        if cls.kind is NodeKind.CONTROL:
            return None if count >= 1 else "a Control node needs at least one child"
        return None

    def _with_conditions(
        self, node: py_trees.behaviour.Behaviour, conditions: dict[str, str], loc: SourceLocation, node_id: str
    ) -> py_trees.behaviour.Behaviour:
        if not conditions:
            return node
        try:
            from .conditions import attach_conditions
        except ImportError:
            raise LoadError(
                f"attribute '{next(iter(conditions))}' needs runtime.tree.conditions, which is not installed", loc, node_id
            ) from None
        wrapped = attach_conditions(node, conditions, loc)
        return node if wrapped is None else wrapped


def throwaway_context() -> RunContext:
    from runtime.io.bus import InProcessBus
    from runtime.io.clock import SimClock
    from .events import EventLog

    clock = SimClock()
    return RunContext(clock=clock, bus=InProcessBus(clock), events=EventLog(clock))


def _select_tree(doc: Document, tree_id: str | None, builder: _Builder) -> TreeDef:
    loc = SourceLocation(doc.display, 0)
    choice = tree_id or doc.main_tree
    if choice:
        if choice in doc.trees:
            return doc.trees[choice]
        found = builder.library.find(choice, loc)
        if found is None:
            what = "--tree" if tree_id else "main_tree_to_execute"
            hint = did_you_mean(choice, doc.trees)
            raise LoadError(f"{what} names BehaviorTree '{choice}', which is not defined (trees: {', '.join(doc.trees) or 'none'}){hint}", loc)
        return found
    if not doc.own_tree_ids:
        raise LoadError("no <BehaviorTree> in this file", loc)
    # Groot2 drops main_tree_to_execute when it saves: run the one tree no other tree uses.
    tops = top_level_trees(doc)
    if len(tops) == 1:
        return doc.trees[tops[0]]
    raise LoadError(
        f"several BehaviorTrees ({', '.join(tops or doc.own_tree_ids)}) are not used as a SubTree by another "
        "and there is no main_tree_to_execute: name the one to run with main_tree_to_execute or --tree",
        loc,
    )


def top_level_trees(doc: Document) -> list[str]:
    """The file's own trees that no tree of the document (includes too) uses as a SubTree."""
    used = {
        element.get("ID")
        for tree in doc.trees.values()
        for element in tree.element.iter("SubTree")
        if element is not tree.element
    }
    return [tree_id for tree_id in doc.own_tree_ids if tree_id not in used]


def _library_for(doc: Document, search_paths: Iterable[Path], objectives_dir: Path | None) -> Library:
    objectives = Path(objectives_dir) if objectives_dir is not None else default_objectives_dir()
    skip = [doc.path] if doc.path else []
    return Library([objectives, *(Path(p) for p in search_paths)], skip=skip)


def load_tree(
    source: Path | str,
    registry: Registry,
    context: RunContext,
    tree_id: str | None = None,
    search_paths: Iterable[Path] = (),
    objectives_dir: Path | None = None,
) -> LoadedTree:
    """Load ``source`` (a path, or XML text) and build the tree to run, bound to ``context``.

    The tree is ``tree_id``, else ``main_tree_to_execute``, else the file's only BehaviorTree.
    Raises LoadError/PortError ("file:line: Node: what") on anything wrong.
    """
    search_paths = [Path(p) for p in search_paths]
    objectives = Path(objectives_dir) if objectives_dir is not None else default_objectives_dir()
    doc = parse_document(source, [objectives, *search_paths])
    builder = _Builder(registry, context, _library_for(doc, search_paths, objectives))
    return _build(builder, doc, _select_tree(doc, tree_id, builder))


def _build(builder: _Builder, doc: Document, tree: TreeDef) -> LoadedTree:
    blackboard = Blackboard()
    root = builder.build_tree(tree, blackboard, [(tree.document.key, tree.id)])
    files = dict.fromkeys(f for d in (doc, *builder.documents.values()) for f in d.files)
    return LoadedTree(root, blackboard, tree.id, doc.path, builder.nodes, tuple(files))


@dataclass
class Validation:
    """What ``validate`` found in a file: the trees it built, and every error, each at its file:line."""

    trees: list[LoadedTree]
    errors: list[ObjectiveRuntimeError]

    def trees_or_raise(self) -> list[LoadedTree]:
        """The trees when nothing is wrong; else the first error is raised."""
        if self.errors:
            raise self.errors[0]
        return self.trees


def validate(
    source: Path | str,
    registry: Registry,
    tree_id: str | None = None,
    search_paths: Iterable[Path] = (),
    objectives_dir: Path | None = None,
    context: Callable[[], RunContext] = throwaway_context,
    check: Callable[[list[LoadedNode], bool], Sequence[ObjectiveRuntimeError]] | None = None,
) -> Validation:
    """Load a file's trees, ``tree_id`` or every BehaviorTree written in it, each on a ``context()``,
    and find every error: a broken node is left out and the rest is built and checked. ``check``
    adds the errors only a world knows (``runtime.app.world_check``). A file that does not parse, or
    names no tree to validate, raises its LoadError.
    """
    search_paths = [Path(p) for p in search_paths]
    objectives = Path(objectives_dir) if objectives_dir is not None else default_objectives_dir()
    doc = parse_document(source, [objectives, *search_paths])
    library = _library_for(doc, search_paths, objectives)
    if tree_id is not None:
        ids = [_select_tree(doc, tree_id, _Builder(registry, throwaway_context(), library)).id]
    else:
        ids = list(doc.own_tree_ids)
        if not ids:
            raise LoadError("no <BehaviorTree> in this file", SourceLocation(doc.display, 0))
        if doc.main_tree and doc.main_tree not in doc.trees:
            _select_tree(doc, None, _Builder(registry, throwaway_context(), library))
    result = Validation([], [])
    for tid in ids:
        builder = _Builder(registry, context(), library, collect=True)
        tree = doc.trees[tid] if tid in doc.trees else _select_tree(doc, tid, builder)
        try:
            loaded = _build(builder, doc, tree)
        except ObjectiveError as err:  # the tree's root itself is broken
            builder.errors.extend([err, *err.also])
            loaded = None
        top_level = tid in top_level_trees(doc)
        if loaded is not None:
            result.trees.append(loaded)
            model = doc.models.get(tid)
            builder.errors.extend(unset_reads(loaded, set(model.ports) if model else set(), top_level))
        if check is not None:
            builder.errors.extend(check([*builder.nodes, *builder.unbuilt], top_level))
        for error in builder.errors:  # a SubTree used by several trees has its errors once
            if all(str(error) != str(seen) for seen in result.errors):
                result.errors.append(error)
    result.errors.sort(key=_written_at)  # stable: a node's own error before its children's on its line
    return result


_NAME = re.compile(r"@?[A-Za-z_][A-Za-z0-9_]*")


def _written_slots(nodes: Iterable[LoadedNode]) -> set[tuple[int, str]]:
    """The blackboard entries (``(id(board), key)``) the tree may write: output ports, a SubTree's
    literal ports, and every name a literal attribute mentions (a script's ``x := 1``,
    SetBlackboard's ``output_key``): more than it writes, never less."""
    slots: set[tuple[int, str]] = set()

    def add(board: Blackboard, key: str) -> None:
        owner, mapped = board.owner(key)
        slots.add((id(owner), mapped))

    for info in nodes:
        node = info.node
        if isinstance(node, SubTree):
            slots.update((id(node.child_blackboard), port) for port in node.literals)
            continue
        board = node_info.blackboard(node)
        if board is None:
            continue
        for binding in node_info.bindings(node).values():
            if binding.key is not None and binding.info.direction is not Direction.INPUT:
                add(board, binding.key)
        for value in info.values.values():
            if not (value.strip().startswith("{") and value.strip().endswith("}")):
                for name in _NAME.findall(value):
                    add(board, name)
    return slots


def unset_reads(loaded: LoadedTree, root_ports: set[str], top_level: bool) -> list[PortError]:
    """Input ports inside a SubTree whose entry nothing in the tree writes: a remapping to a
    caller's entry nobody sets, or a caller's entry the SubTree does not share (no ``_autoremap``).
    A root entry counts as given when it is one of the root tree's ``root_ports`` (its
    TreeNodesModel), or when the root tree is itself a SubTree (not ``top_level``) or the node is
    on the root's own blackboard: its callers, or ``objective run --set``, may give it."""
    written = _written_slots(loaded.nodes)
    errors: list[PortError] = []
    for info in loaded.nodes:
        node = info.node
        board = node_info.blackboard(node)
        if board is None or isinstance(node, SubTree):
            continue
        for port, binding in node_info.bindings(node).items():
            if binding.key is None or binding.info.direction is not Direction.INPUT:
                continue
            owner, key = board.owner(binding.key)
            given = owner is loaded.blackboard and (not top_level or key in root_ports or board is owner)
            if given or (id(owner), key) in written:
                continue
            reason = board.unset_reason(binding.key, lambda b, k: (id(b), k) in written)
            errors.append(info.error(PortError(f"port '{port}' reads {reason}", info.location, info.xml_id)))
    return errors


def _written_at(error: ObjectiveRuntimeError) -> tuple[str, int]:
    """Where the user wrote what an error is about: the outermost SubTree call, else the node."""
    where = error.callers[0][0] if error.callers else error.location
    return (where.file, where.line) if where is not None else ("", 0)

