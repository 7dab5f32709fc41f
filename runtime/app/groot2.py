"""Live monitoring in Groot2: BehaviorTree.CPP's Groot2 protocol, served for a running tree.

``objective run --groot2 [PORT]`` (and ``objective server --groot2``) answer Groot2 as
BehaviorTree.CPP's ``Groot2Publisher`` does: a ZeroMQ REP socket on PORT (1667 by default)
and a PUB socket on PORT + 1. Every request is a multipart message whose first part is a
6-byte header (protocol 2, a request type letter, a 32-bit request id); every reply starts with
that header and the 16-byte id of the tree being shown, followed by:

==================  ====  ===============================================================
request             type  reply
==================  ====  ===============================================================
full tree           T     the tree as XML: every node with its ``_uid``, every SubTree
                          instance as a ``<BehaviorTree _fullpath=...>``, a TreeNodesModel
status              S     3 bytes per node: its uid (uint16, little-endian), its status
blackboard          B     MessagePack of ``{name: {entry: value}}`` for the ``;``-separated
                          blackboard names (a tree's ID, or a SubTree's ``_fullpath``);
                          a ROS message as a map of its fields
hooks dump          D     ``[]``: there are no hooks
remove/disable all  A, X  the header alone (nothing to remove)
toggle recording    r     ``start``: the wall time in microseconds; ``stop``: the header
transitions         t     9 bytes per status change since the last request: microseconds
                          since ``start`` (6 bytes), uid (2), status (1)
==================  ====  ===============================================================

Hooks and breakpoints (``I``; ``R`` and ``U`` on a node without one) are refused with
BehaviorTree.CPP's own error reply, ``["error", "<why>"]``: a breakpoint would stop the tick
loop while the robot moves, so the monitor is read-only. Unknown requests, headers of the wrong
size and requests missing their second part get the same error replies BehaviorTree.CPP sends.
Groot2's requests are its heartbeat: ``connected`` says whether one arrived in the last
``HEARTBEAT_S`` seconds.

A client can never slow the tick loop by more than a bounded share: a request frame over
``MAX_REQUEST_BYTES`` is dropped by ZeroMQ before it is read (the client is disconnected); a
blackboard request names at most ``MAX_BLACKBOARD_NAMES`` blackboards and its reply is at most
``MAX_REPLY_BYTES`` (else an error reply saying so); the tick side (``update``) never waits for
an answer being computed (the lock guards only the snapshot the answers read); and the server
thread rests after each answer so that its work takes at most ``MonitorLimits.max_share`` of
the time (``rest_after``).

Statuses follow BehaviorTree.CPP's codes: IDLE 0, RUNNING 1, SUCCESS 2, FAILURE 3, and 10 +
the previous status for a node that went back to IDLE (a finished or halted node), so Groot2
shows where the run went; a skipped node keeps its code, as BehaviorTree.CPP reports no change
for it. The runner calls ``update`` after every tick; the server
thread answers from that snapshot and never touches the tree's statuses itself.

Needs the ``monitor`` extra (``pip install 'objective-runtime[monitor]'``: pyzmq, msgpack).
"""
from __future__ import annotations

import enum
import json
import logging
import os
import struct
import threading
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Iterable

import py_trees

from runtime.tree import node_info
from runtime.tree.behavior import NodeKind, Status
from runtime.tree.controls import Visit
from runtime.errors import ObjectiveError
from runtime.tree.ports import Direction, PortType
from runtime.tree.subtree import SubTree

from runtime.tree.loader import METADATA_ATTRIBUTES
from .observer import RunObserver

if TYPE_CHECKING:
    from runtime.io.interrupt import StopRequest
    from runtime.tree.blackboard import Blackboard
    from runtime.tree.loader import LoadedTree

    from .runner import RunResult

DEFAULT_PORT = 1667
PROTOCOL_ID = 2
HEADER = struct.Struct("<BBI")
"""A request header: protocol, request type (a letter), request id."""
HEARTBEAT_S = 5.0
"""Groot2 counts as connected this long after its last request (BehaviorTree.CPP's default)."""
RECEIVE_TIMEOUT_MS = 100
MAX_TRANSITIONS = 1000
"""Transitions kept while recording (the oldest are dropped), as BehaviorTree.CPP keeps."""
MAX_REQUEST_BYTES = 64 << 10
"""The largest request frame read (Groot2's are a few hundred bytes: a header, blackboard names)."""
MAX_BLACKBOARD_NAMES = 256
MAX_REPLY_BYTES = 1 << 20
MAX_SHARE = 0.1
"""The share of the time the server thread may work (it competes with the tick loop for the GIL)."""
HOOKS_REFUSED = ("hooks and breakpoints are not supported: objective-runtime's Groot2 monitor is read-only "
                 "(a breakpoint would stop the tick loop while the robot moves)")
_log = logging.getLogger("objective")


class Request(enum.Enum):
    FULL_TREE = b"T"
    STATUS = b"S"
    BLACKBOARD = b"B"
    HOOK_INSERT = b"I"
    HOOK_REMOVE = b"R"
    BREAKPOINT_REACHED = b"N"
    BREAKPOINT_UNLOCK = b"U"
    HOOKS_DUMP = b"D"
    REMOVE_ALL_HOOKS = b"A"
    DISABLE_ALL_HOOKS = b"X"
    TOGGLE_RECORDING = b"r"
    GET_TRANSITIONS = b"t"


class Code(enum.IntEnum):
    """BehaviorTree.CPP's NodeStatus values, as the status reply carries them."""

    IDLE = 0
    RUNNING = 1
    SUCCESS = 2
    FAILURE = 3
    SKIPPED = 4


IDLE_AFTER = 10
"""Added to the previous status of a node that went back to IDLE."""
_CODES = {Status.RUNNING: Code.RUNNING, Status.SUCCESS: Code.SUCCESS, Status.FAILURE: Code.FAILURE}


@dataclass(frozen=True)
class MonitorLimits:
    """What one client may cost the process."""

    max_request_bytes: int = MAX_REQUEST_BYTES
    max_blackboard_names: int = MAX_BLACKBOARD_NAMES
    max_reply_bytes: int = MAX_REPLY_BYTES
    max_share: float = MAX_SHARE


@dataclass(frozen=True)
class Groot2Options:
    port: int = DEFAULT_PORT
    """The request port; the publisher takes ``port + 1``. 0: any free pair of ports."""
    host: str = "127.0.0.1"
    """The interface to listen on (``0.0.0.0``: every interface, as BehaviorTree.CPP does)."""
    limits: MonitorLimits = field(default_factory=MonitorLimits)


# ------------------------------------------------------------------------------------------------
# The tree as Groot2 sees it
# ------------------------------------------------------------------------------------------------
@dataclass
class MonitoredTree:
    """A loaded tree numbered as BehaviorTree.CPP numbers it: the XML, the nodes, the blackboards."""

    xml: str
    nodes: list[tuple[int, py_trees.behaviour.Behaviour]]
    """(uid, node) in the order of the status reply: tree by tree, each tree's nodes depth-first."""
    blackboards: dict[str, "Blackboard"]
    """Each tree's own blackboard, by the name Groot2 asks for it (the tree ID, or the SubTree's path)."""
    uuid: bytes = field(default_factory=lambda: new_tree_uuid())


def new_tree_uuid() -> bytes:
    """A random version-4 UUID (16 bytes): the id replies carry, new for every tree shown."""
    data = bytearray(os.urandom(16))
    data[6] = (data[6] & 0x0F) | 0x40
    data[8] = (data[8] & 0x3F) | 0x80
    return bytes(data)


def _unwrap(node: py_trees.behaviour.Behaviour) -> py_trees.behaviour.Behaviour:
    """The node a transparent wrapper (a condition guard) stands for."""
    while node_info.is_transparent(node):
        node = node.children[0]
    return node


def _children(node: py_trees.behaviour.Behaviour) -> list[py_trees.behaviour.Behaviour]:
    return [] if isinstance(node, SubTree) else [_unwrap(c) for c in node.children]


def monitored_tree(loaded: "LoadedTree") -> MonitoredTree:
    """Number ``loaded`` as BehaviorTree.CPP does (uids from 1, depth-first, a SubTree's nodes
    right after the SubTree node) and write the XML its ``Groot2Publisher`` sends."""
    root = ET.Element("root", BTCPP_format="4")
    trees: list[tuple[ET.Element, list[int]]] = []  # each tree's element and its uids, in creation order
    nodes: dict[int, py_trees.behaviour.Behaviour] = {}
    blackboards: dict[str, Blackboard] = {loaded.tree_id: loaded.blackboard}
    models: dict[str, tuple[NodeKind, type]] = {}
    uid = 0

    def add_tree(tree_id: str, path: str, top: py_trees.behaviour.Behaviour) -> None:
        element = ET.SubElement(root, "BehaviorTree", ID=tree_id, _fullpath=path)
        uids: list[int] = []
        trees.append((element, uids))
        add_node(_unwrap(top), element, uids, path)

    def add_node(node: py_trees.behaviour.Behaviour, parent: ET.Element, uids: list[int], path: str) -> None:
        nonlocal uid
        uid += 1
        nodes[uid] = node
        uids.append(uid)
        info = loaded.info(node)
        xml_id = info.xml_id if info is not None else node_info.xml_id(node)
        written = info.values if info is not None else {}
        if isinstance(node, SubTree):
            named = node.name if node.name != xml_id else f"{xml_id}::{uid}"
            sub_path = (path + "/" if path else "") + named
            element = ET.SubElement(parent, "SubTree", ID=xml_id, _fullpath=sub_path, _uid=str(uid))
            element.attrib.update(_attributes(written, node))
            models.setdefault("SubTree", (NodeKind.SUBTREE, type(node)))
            blackboards[sub_path] = node.child_blackboard
            add_tree(xml_id, sub_path, node.children[0])
            return
        element = ET.SubElement(parent, xml_id, name=node.name, _uid=str(uid))
        element.attrib.update(_attributes(written, node))
        models.setdefault(xml_id, (node_info.kind(node) or NodeKind.ACTION, type(node)))
        for child in _children(node):
            add_node(child, element, uids, path)

    add_tree(loaded.tree_id, "", loaded.root)
    model_root = ET.SubElement(root, "TreeNodesModel")
    for xml_id, (kind, cls) in sorted(models.items()):
        model_root.append(_model(xml_id, kind, cls))
    ET.indent(root, space="    ")
    order = [(u, nodes[u]) for _, uids in trees for u in uids]
    return MonitoredTree(ET.tostring(root, encoding="unicode"), order, blackboards)


def _attributes(written: dict[str, str], node: Any) -> dict[str, str]:
    """The ports as written, every unwritten port that has a default, and the condition scripts."""
    attrs = {k: v for k, v in written.items() if k not in ("name", "ID", "_autoremap") and k not in METADATA_ATTRIBUTES}
    for port in node_info.ports(type(node)):
        if port.name not in attrs and port.has_default and port.direction is not Direction.OUTPUT:
            attrs[port.name] = port.describe_default()
    return attrs


def _model(xml_id: str, kind: NodeKind, cls: type) -> ET.Element:
    element = ET.Element(kind.value, ID=xml_id)
    for port in node_info.ports(cls):
        attrs = {"name": port.name, "type": "std::string" if port.type is PortType.STRING else port.type.value}
        if port.has_default:
            attrs["default"] = port.describe_default()
        ET.SubElement(element, port.direction.value, attrs).text = port.description or None
    return element


# ------------------------------------------------------------------------------------------------
# Statuses
# ------------------------------------------------------------------------------------------------
def status_code(node: py_trees.behaviour.Behaviour, reported: Status | None, previous: int) -> int:
    """The status byte of ``node`` after a tick.

    ``reported`` is the status the node reported in that tick (None if it was not ticked) and
    ``previous`` its byte before. A RUNNING, SUCCESS or FAILURE node shows that status; a node
    that is idle again (its parent finished or halted it) shows 10 + the status it had, as
    BehaviorTree.CPP reports a node back to IDLE. A skipped node keeps its byte: BehaviorTree.CPP
    reports no change for it.
    """
    code = _CODES.get(node.status)
    if code is not None:
        return int(code)
    if reported in _CODES:
        return IDLE_AFTER + int(_CODES[reported])
    if Code.RUNNING <= previous <= Code.SKIPPED:
        return IDLE_AFTER + previous
    return previous


def reported_statuses(visited: Iterable[Visit]) -> dict[int, Status]:
    """The status each node reported in a tick, by ``id``; a node a condition guard decided
    (``_successIf`` ...) without ticking it reports the guard's result, as in BehaviorTree.CPP."""
    reported: dict[int, Status] = {}
    for node, status, _ in visited:
        reported[id(node)] = status
        if node_info.is_transparent(node):
            reported.setdefault(id(_unwrap(node)), status)
    return reported


def status_buffer(uids: list[int], codes: list[int]) -> bytes:
    return b"".join(struct.pack("<HB", uid, code) for uid, code in zip(uids, codes))


def blackboard_dump(boards: dict[str, "Blackboard"], request: str,
                    max_names: int = MAX_BLACKBOARD_NAMES) -> dict[str, dict[str, Any] | None]:
    """``{name: {entry: value}}`` for the ``;``-separated names in ``request`` that exist; an
    empty blackboard is None (JSON null), as BehaviorTree.CPP exports it. ValueError for a
    request naming more than ``max_names`` blackboards (each counted once).

    Values are sent as ``_plain`` makes them (a ROS message as a map of its fields)."""
    names = list(dict.fromkeys(request.split(";")))
    if len(names) > max_names:
        raise ValueError(f"a blackboard request names at most {max_names} blackboards, got {len(names)}")
    out: dict[str, dict[str, Any] | None] = {}
    for name in names:
        board = boards.get(name)
        if board is not None:
            out[name] = {key: _plain(value) for key, value in sorted(board.local_entries().items())} or None
    return out


def rest_after(busy_s: float, max_share: float) -> float:
    """How long the server rests after ``busy_s`` of work, so that its work is at most
    ``max_share`` of the time."""
    return busy_s * (1.0 - max_share) / max_share


def _plain(value: Any) -> Any:
    """``value`` as MessagePack carries it: numbers, text, lists; a ROS message as a map of its
    fields (``{"pose": {"position": {"x": ...}}}``); anything else as its text."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    fields = getattr(value, "get_fields_and_field_types", None)
    if callable(fields):
        return {name: _plain(getattr(value, name)) for name in fields()}
    return str(value)


# ------------------------------------------------------------------------------------------------
# The server
# ------------------------------------------------------------------------------------------------
def _import_zmq() -> tuple[Any, Any]:
    try:
        import msgpack
        import zmq
    except ImportError as err:
        raise ObjectiveError(
            f"--groot2 needs the monitor extra ({err.name} is not installed): "
            "pip install 'objective-runtime[monitor]'"
        ) from None
    return zmq, msgpack


class Groot2Server:
    """Answers Groot2 for the tree ``show`` was last given, from a thread of its own.

    ``show(loaded)`` before a run, ``update()`` after every tick (the runner does both through
    ``Groot2Observer``), ``close()`` at the end. Between runs it keeps answering with the last
    tree and its final statuses; before the first, a full-tree request gets an error reply.
    """

    def __init__(self, options: Groot2Options) -> None:
        self._zmq, self._msgpack = _import_zmq()
        self._context = self._zmq.Context()
        self._server = self._context.socket(self._zmq.REP)
        self._publisher = self._context.socket(self._zmq.PUB)
        for sock in (self._server, self._publisher):
            sock.setsockopt(self._zmq.LINGER, 0)
        self._server.setsockopt(self._zmq.RCVTIMEO, RECEIVE_TIMEOUT_MS)
        self._server.setsockopt(self._zmq.SNDTIMEO, 1000)
        self._server.setsockopt(self._zmq.MAXMSGSIZE, options.limits.max_request_bytes)  # larger: never read
        self.limits = options.limits
        try:
            self.port = self._bind(options)
        except self._zmq.ZMQError as err:
            self._context.destroy(linger=0)
            raise ObjectiveError(f"--groot2: cannot listen on {options.host} ports {options.port} and "
                                 f"{options.port + 1}: {err} (choose another port, or 0 for any free one)") from None
        self.host = options.host
        self._lock = threading.Lock()
        self._tree: MonitoredTree | None = None
        self._uids: list[int] = []
        self._codes: list[int] = []
        self._status = b""
        self._recording_start_us: int | None = None
        self._transitions: list[bytes] = []
        self._last_request = -float("inf")
        self._running = True
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="groot2", daemon=True)
        self._thread.start()

    def _bind(self, options: Groot2Options) -> int:
        address = f"tcp://{options.host}"
        if options.port:
            self._server.bind(f"{address}:{options.port}")
            self._publisher.bind(f"{address}:{options.port + 1}")
            return options.port
        for _ in range(50):  # any free pair: the request port, and the next one free too
            port: int = self._server.bind_to_random_port(address, min_port=20000, max_port=60000)
            try:
                self._publisher.bind(f"{address}:{port + 1}")
                return port
            except self._zmq.ZMQError:
                self._server.unbind(f"{address}:{port}")
        raise self._zmq.ZMQError(msg="no free pair of ports")

    @property
    def url(self) -> str:
        return f"tcp://{self.host}:{self.port}"

    @property
    def connected(self) -> bool:
        """Whether Groot2 sent a request in the last ``HEARTBEAT_S`` seconds."""
        return time.monotonic() - self._last_request < HEARTBEAT_S

    # -- the runner's side ---------------------------------------------------------------------
    def show(self, loaded: "LoadedTree") -> None:
        """Serve ``loaded`` from now on (a new tree id: Groot2 loads the tree again)."""
        tree = monitored_tree(loaded)
        with self._lock:
            self._tree = tree
            self._uids = [uid for uid, _ in tree.nodes]
            self._codes = [int(Code.IDLE)] * len(tree.nodes)
            self._status = status_buffer(self._uids, self._codes)

    def update(self, visited: Iterable[Visit] = ()) -> None:
        """Take the statuses of the tree's nodes now: after a tick (``visited``: what it ticked,
        with the status each reported), or after the halt."""
        tree = self._tree
        if tree is None:
            return
        reported = reported_statuses(visited)
        codes = [status_code(node, reported.get(id(node)), previous)
                 for (_, node), previous in zip(tree.nodes, self._codes)]
        if codes == self._codes:
            return
        with self._lock:
            if self._recording_start_us is not None:
                now_us = _now_us() - self._recording_start_us
                for uid, old, new in zip(self._uids, self._codes, codes):
                    if old != new:
                        raw = Code.IDLE if new >= IDLE_AFTER else new
                        self._transitions.append(struct.pack("<Q", now_us)[:6] + struct.pack("<HB", uid, raw))
                del self._transitions[:-MAX_TRANSITIONS]
            self._codes = codes
            self._status = status_buffer(self._uids, codes)

    def close(self) -> None:
        self._running = False
        self._closing.set()
        self._thread.join(timeout=2.0)
        self._context.destroy(linger=0)

    def observer(self) -> "Groot2Observer":
        """The run observer that shows a run's tree here."""
        return Groot2Observer(self)

    def __enter__(self) -> "Groot2Server":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- the server thread ---------------------------------------------------------------------
    def _serve(self) -> None:
        while self._running:
            try:
                request = self._server.recv_multipart()
            except self._zmq.Again:
                continue
            except self._zmq.ZMQError:
                return
            if not self.connected:
                _log.info("Groot2: a client connected to %s", self.url)
            self._last_request = started = time.monotonic()
            try:
                reply = self.answer(request)
            except Exception as err:  # a malformed request body: say so, keep serving
                reply = [b"error", f"{type(err).__name__}: {err}".encode()]
            try:
                self._server.send_multipart(reply)
            except self._zmq.ZMQError:
                return
            self._closing.wait(rest_after(time.monotonic() - started, self.limits.max_share))

    def answer(self, request: list[bytes]) -> list[bytes]:
        """The reply to one request (a list of frames), as BehaviorTree.CPP's publisher gives it."""
        if len(request[0]) != HEADER.size:
            return _error("wrong request header")
        _, letter, request_id = HEADER.unpack(request[0])
        try:
            kind = Request(bytes([letter]))
        except ValueError:
            return _error("Request not recognized")
        with self._lock:  # (held only to read the snapshot: ``update`` never waits for an answer)
            tree, status = self._tree, self._status
        if tree is None:
            return _error("no tree is running yet")
        header = HEADER.pack(PROTOCOL_ID, letter, request_id) + tree.uuid
        body = request[1].decode() if len(request) == 2 else None
        needs_body = (Request.BLACKBOARD, Request.HOOK_INSERT, Request.HOOK_REMOVE,
                      Request.BREAKPOINT_UNLOCK, Request.TOGGLE_RECORDING)
        if kind in needs_body and body is None:
            return _error("must be 2 parts message")
        if kind is Request.FULL_TREE:
            return [header, tree.xml.encode()]
        if kind is Request.STATUS:
            return [header, status]
        if kind is Request.BLACKBOARD:
            try:
                packed = self._msgpack.packb(blackboard_dump(tree.blackboards, body or "", self.limits.max_blackboard_names))
            except ValueError as err:
                return _error(str(err))
            if len(packed) > self.limits.max_reply_bytes:
                return _error(f"the blackboards asked for take {len(packed)} bytes, over the "
                              f"{self.limits.max_reply_bytes} a reply may have: ask for fewer")
            return [header, packed]
        with self._lock:
            if kind is Request.HOOKS_DUMP:
                return [header, b"[]"]
            if kind in (Request.REMOVE_ALL_HOOKS, Request.DISABLE_ALL_HOOKS):
                return [header]
            if kind is Request.HOOK_INSERT:
                return _error(HOOKS_REFUSED)
            if kind in (Request.HOOK_REMOVE, Request.BREAKPOINT_UNLOCK):
                json.loads(body or "")["uid"]  # a malformed body is answered as such
                return _error("Node ID not found")
            if kind is Request.TOGGLE_RECORDING:
                return [header, *self._toggle_recording(body or "")]
            if kind is Request.GET_TRANSITIONS:
                transitions, self._transitions = self._transitions, []
                return [header, b"".join(transitions)]
        return _error("Request not recognized")

    def _toggle_recording(self, command: str) -> list[bytes]:
        if command == "start":
            self._recording_start_us = _now_us()
            self._transitions = []
            return [str(int(time.time() * 1e6)).encode()]
        if command == "stop":
            self._recording_start_us = None
        return []


def _error(message: str) -> list[bytes]:
    return [b"error", message.encode()]


def _now_us() -> int:
    return time.monotonic_ns() // 1000


class Groot2Observer(RunObserver):
    """Connects a ``Groot2Server`` to a run: ``started(loaded)`` shows the tree, ``ticked`` takes
    its statuses, and the run's end (``finished`` or ``aborted``) takes them once more, after the halt."""

    def __init__(self, server: Groot2Server) -> None:
        self.server = server

    def started(self, loaded: "LoadedTree") -> None:
        self.server.show(loaded)

    def ticked(self, now_s: float, visited: list[Visit]) -> None:
        self.server.update(visited)

    def finished(self, result: "RunResult", stop: "StopRequest | None") -> None:
        self.server.update()

    def aborted(self, error: BaseException, stop: "StopRequest | None") -> None:
        self.server.update()
