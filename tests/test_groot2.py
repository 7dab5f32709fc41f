"""Live monitoring in Groot2, checked against BehaviorTree.CPP's own Groot2Publisher.

The same tree is loaded in both; the same requests go to both over ZeroMQ; the replies must be
equal (the tree id in the reply header is random in both and is compared for shape only).
"""
from __future__ import annotations

import json
import signal
import struct
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from typing import Any

import msgpack
import pytest
import zmq

import behaviortreepy as btcpp
from runtime.tree.behavior import Status
from runtime.tree.controls import tick_tree
from runtime.app.groot2 import HOOKS_REFUSED, Groot2Options, Groot2Server, monitored_tree
from runtime.tree.loader import load_tree
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, make_context, run_tree

pytestmark = pytest.mark.timeout(60)

XML = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence name="top">
      <Script code="x:=3; s:='hi'; f:=2.5"/>
      <SubTree ID="Sub" y="{x}"/>
      <SubTree ID="Sub" name="second" y="7"/>
      <RunOnce>
        <AlwaysSuccess/>
      </RunOnce>
      <AlwaysFailure _skipIf="x == 3"/>
      <ReactiveSequence>
        <AlwaysSuccess _successIf="x == 3"/>
        <Inverter><AlwaysFailure/></Inverter>
      </ReactiveSequence>
      <Parallel success_count="1">
        <AlwaysSuccess/>
      </Parallel>
      <Sleep msec="50"/>
      <ForceSuccess>
        <Timeout msec="20">
          <Sleep msec="1000"/>
        </Timeout>
      </ForceSuccess>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Sub">
    <Fallback>
      <AlwaysFailure/>
      <Script code="z:=y"/>
    </Fallback>
  </BehaviorTree>
</root>"""


def header(letter: str, request_id: int = 1234) -> bytes:
    return struct.pack("<BBI", 2, ord(letter), request_id)


class Client:
    """A Groot2-like client: a REQ socket with bounded waits."""

    def __init__(self, port: int) -> None:
        self.context = zmq.Context()
        self.socket = self.context.socket(zmq.REQ)
        self.socket.setsockopt(zmq.RCVTIMEO, 3000)
        self.socket.setsockopt(zmq.SNDTIMEO, 3000)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.connect(f"tcp://127.0.0.1:{port}")

    def ask(self, *parts: bytes) -> list[bytes]:
        self.socket.send_multipart(list(parts))
        return self.socket.recv_multipart()

    def close(self) -> None:
        self.context.destroy(linger=0)


def free_pair() -> int:
    """A port that is free, with the next one free too (for BehaviorTree.CPP's publisher)."""
    context = zmq.Context()
    try:
        for _ in range(50):
            a, b = context.socket(zmq.REP), context.socket(zmq.PUB)
            try:
                port = a.bind_to_random_port("tcp://127.0.0.1", min_port=20000, max_port=60000)
                b.bind(f"tcp://127.0.0.1:{port + 1}")
                return port
            except zmq.ZMQError:
                continue
            finally:
                a.close(0)
                b.close(0)
        raise RuntimeError("no free pair of ports")
    finally:
        context.destroy(linger=0)


@pytest.fixture(scope="module")
def registry():
    from runtime.tree.builtin import register

    registry = Registry()
    register(registry)
    return registry


@pytest.fixture
def both(registry):
    """(ours: server, loaded tree, context; theirs: publisher, tree; a client for each)."""
    options = RunOptions()
    context = make_context(options)
    loaded = load_tree(XML, registry, context)
    server = Groot2Server(Groot2Options(port=0))
    server.show(loaded)
    tree = btcpp.BehaviorTreeFactory().create_tree_from_text(XML)
    port = free_pair()
    publisher = btcpp.Groot2Publisher(tree, port)
    ours, theirs = Client(server.port), Client(port)
    yield (server, loaded, context), tree, ours, theirs
    ours.close()
    theirs.close()
    server.close()
    del publisher


def tree_part(xml: bytes) -> list[ET.Element]:
    return ET.fromstring(xml).findall("BehaviorTree")


def same_element(a: ET.Element, b: ET.Element) -> bool:
    return (a.tag, a.attrib) == (b.tag, b.attrib) and len(a) == len(b) and all(map(same_element, a, b))


def status_codes(buffer: bytes) -> dict[int, int]:
    return dict(struct.unpack("<HB", buffer[i:i + 3]) for i in range(0, len(buffer), 3))


def reply_header(reply: list[bytes]) -> tuple[bytes, int]:
    """The request part of a reply's header, and the length of the tree id after it."""
    return reply[0][:6], len(reply[0]) - 6


def test_the_full_tree_is_the_xml_behaviortree_cpp_sends(both):
    (_, _, _), _, ours, theirs = both
    mine, real = ours.ask(header("T")), theirs.ask(header("T"))
    assert reply_header(mine) == reply_header(real) == (header("T"), 16)
    assert len(mine) == len(real) == 2
    ours_trees, real_trees = tree_part(mine[1]), tree_part(real[1])
    assert [t.attrib for t in ours_trees] == [t.attrib for t in real_trees] == [
        {"ID": "Main", "_fullpath": ""}, {"ID": "Sub", "_fullpath": "Sub::3"}, {"ID": "Sub", "_fullpath": "second"}]
    for a, b in zip(ours_trees, real_trees):
        assert same_element(a, b), (ET.tostring(a), ET.tostring(b))
    # Every node the tree uses has its model, of the same kind as BehaviorTree.CPP's.
    real_models = {m.get("ID"): m.tag for m in ET.fromstring(real[1]).find("TreeNodesModel")}
    our_models = {m.get("ID"): m.tag for m in ET.fromstring(mine[1]).find("TreeNodesModel")}
    used = {e.tag for t in real_trees for e in t.iter() if e.tag != "BehaviorTree"}
    assert {i: our_models.get(i) for i in used} == {i: real_models[i] for i in used}


def test_statuses_before_during_and_after_a_run_are_behaviortree_cpps(both):
    (server, loaded, context), tree, ours, theirs = both
    assert ours.ask(header("S"))[1] == theirs.ask(header("S"))[1]  # all IDLE

    # One tick: everything before Sleep done, Sleep RUNNING (50 ms on both clocks).
    assert tree.tick_once() == btcpp.NodeStatus.RUNNING
    context.clock.advance(0.01)
    tick = tick_tree(loaded.root)
    assert tick.status is Status.RUNNING
    server.update(tick.visited)
    mine, real = ours.ask(header("S"))[1], theirs.ask(header("S"))[1]
    assert mine == real
    codes = status_codes(mine)
    assert codes[1] == 1 and codes[20] == 1 and codes[23] == 0  # the Sequence and the first Sleep are RUNNING

    # To the end: every node idle again, showing what it did (10 + status).
    assert tree.tick_while_running() == btcpp.NodeStatus.SUCCESS
    while True:
        context.clock.advance(0.01)
        tick = tick_tree(loaded.root)
        server.update(tick.visited)
        if tick.status is not Status.RUNNING:
            break
    assert tick.status is Status.SUCCESS
    mine, real = ours.ask(header("S"))[1], theirs.ask(header("S"))[1]
    assert mine == real
    # IDLE after SUCCESS, the AlwaysFailures' and the Timeout's IDLE after FAILURE, the skipped node
    # never left IDLE, the Sleep the Timeout halted IDLE after RUNNING
    assert set(mine[2::3]) == {0, 11, 12, 13} and status_codes(mine)[23] == 11


def test_blackboards_are_behaviortree_cpps(both):
    (server, loaded, context), tree, ours, theirs = both
    tree.tick_while_running()
    run_tree(loaded, context, RunOptions(), [server.observer()])
    names = b"Main;Sub::3;second;nope"
    mine, real = ours.ask(header("B"), names), theirs.ask(header("B"), names)
    assert reply_header(mine) == reply_header(real)
    assert msgpack.unpackb(mine[1]) == msgpack.unpackb(real[1]) == {
        "Main": {"f": 2.5, "s": "hi", "x": 3}, "Sub::3": {"z": 3}, "second": {"y": "7", "z": "7"}}


@pytest.mark.parametrize("request_parts", [
    [b"abc"],                                   # a header of the wrong size
    [header("Z")],                              # an unknown request
    [header("B")],                              # a blackboard request without its names
    [header("D")],                              # hooks dump: none
    [header("A")],                              # remove all hooks
    [header("X")],                              # disable all hooks
    [header("R"), b'{"uid": 2, "position": 0}'],  # remove a hook that does not exist
    [header("r"), b"stop"],                     # stop a recording
])
def test_other_requests_are_answered_as_behaviortree_cpp_answers(both, request_parts):
    _, _, ours, theirs = both
    mine, real = ours.ask(*request_parts), theirs.ask(*request_parts)
    assert [mine[0][:6], *mine[1:]] == [real[0][:6], *real[1:]]


def test_hooks_are_refused_with_a_clear_answer(both):
    _, _, ours, _ = both
    hook = json.dumps({"enabled": True, "uid": 2, "mode": 0, "once": False, "desired_status": "SUCCESS",
                       "position": 0}).encode()
    assert ours.ask(header("I"), hook) == [b"error", HOOKS_REFUSED.encode()]
    assert ours.ask(header("D")) [1] == b"[]"
    assert ours.ask(header("I"), b"not json") == [b"error", HOOKS_REFUSED.encode()]
    assert ours.ask(header("U"), b"not json")[0] == b"error"  # a malformed body: an error, and it still serves
    assert ours.ask(header("S"))[0][:6] == header("S")


def test_recording_gives_the_transitions_of_a_run(both):
    (server, loaded, context), _, ours, _ = both
    start = ours.ask(header("r"), b"start")
    assert int(start[1]) > 1_700_000_000_000_000  # the wall time in microseconds
    run_tree(loaded, context, RunOptions(), [server.observer()])
    data = ours.ask(header("t"))[1]
    transitions = [struct.unpack("<HB", data[i + 6:i + 9]) for i in range(0, len(data), 9)]
    assert (1, 1) in transitions and (1, 0) in transitions  # the Sequence went RUNNING, then back to IDLE
    assert ours.ask(header("t"))[1] == b""  # each transition is given once


def test_the_tree_id_changes_with_the_tree(both, registry):
    (server, loaded, context), _, ours, _ = both
    first = ours.ask(header("S"))[0][6:]
    server.show(load_tree(XML, registry, context))
    assert ours.ask(header("S"))[0][6:] != first


def test_objective_run_groot2_serves_and_a_taken_port_is_an_error(tmp_path):
    port = free_pair()
    blocker = zmq.Context()
    sock = blocker.socket(zmq.REP)
    sock.bind(f"tcp://127.0.0.1:{port}")
    try:
        tree = tmp_path / "t.xml"
        tree.write_text(XML)
        proc = subprocess.run([sys.executable, "-m", "runtime.app.cli", "run", str(tree), "--groot2", str(port)],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2
        assert f"--groot2: cannot listen on 127.0.0.1 ports {port} and {port + 1}" in proc.stderr
        assert "Traceback" not in proc.stderr
    finally:
        blocker.destroy(linger=0)
    # A realtime run watched mid-run: the tree, then its Wait RUNNING; SIGINT still halts it.
    tree.write_text('<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence><Wait name="long" seconds="30"/>'
                    "</Sequence></BehaviorTree></root>")
    proc = subprocess.Popen([sys.executable, "-m", "runtime.app.cli", "run", str(tree), "--realtime", "--groot2", "0"],
                            stderr=subprocess.PIPE, text=True)
    try:
        lines = [proc.stderr.readline()]
        while "Groot2: connect to" not in lines[-1] and lines[-1] and len(lines) < 20:
            lines.append(proc.stderr.readline())
        line = lines[-1]
        assert line.startswith("[INFO] Groot2: connect to 127.0.0.1 (port "), lines
        client = Client(int(line.rsplit("port ", 1)[1].rstrip(")\n")))
        try:
            deadline = time.monotonic() + 20
            while client.ask(header("S"))[0] == b"error" or status_codes(client.ask(header("S"))[1]) != {1: 1, 2: 1}:
                assert time.monotonic() < deadline, "the run never showed its Wait RUNNING"
                time.sleep(0.05)
            assert '<Wait name="long" _uid="2" seconds="30"' in client.ask(header("T"))[1].decode()
        finally:
            client.close()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and "Traceback" not in err, err


def test_without_the_monitor_extra_groot2_says_what_to_install(monkeypatch):
    from runtime.errors import ObjectiveError

    monkeypatch.setitem(sys.modules, "zmq", None)  # as if pyzmq were not installed
    with pytest.raises(ObjectiveError, match=r"^--groot2 needs the monitor extra \(zmq is not installed\): "
                                             r"pip install 'objective-runtime\[monitor\]'$"):
        Groot2Server(Groot2Options(port=0))


def test_before_any_tree_a_request_gets_an_error_reply():
    with Groot2Server(Groot2Options(port=0)) as server:
        assert not server.connected
        client = Client(server.port)
        try:
            assert client.ask(header("T")) == [b"error", b"no tree is running yet"]
            assert server.connected  # any request is Groot2's heartbeat
        finally:
            client.close()


NESTED = """<root BTCPP_format="4" main_tree_to_execute="Outer">
  <BehaviorTree ID="Outer">
    <Sequence>
      <SubTree ID="Middle" name="mid"/>
      <Precondition if="false" else="SUCCESS">
        <Sleep msec="{never}"/>
      </Precondition>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Middle">
    <Sequence>
      <SubTree ID="Inner"/>
      <SubTree ID="Inner" name="again"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Inner">
    <Script code="depth := 2"/>
  </BehaviorTree>
</root>"""


def test_nested_subtrees_and_unset_entries_are_behaviortree_cpps(registry):
    context = make_context(RunOptions())
    loaded = load_tree(NESTED, registry, context)
    tree = btcpp.BehaviorTreeFactory().create_tree_from_text(NESTED)
    port = free_pair()
    publisher = btcpp.Groot2Publisher(tree, port)
    with Groot2Server(Groot2Options(port=0)) as server:
        ours, theirs = Client(server.port), Client(port)
        try:
            tree.tick_while_running()
            run_tree(loaded, context, RunOptions(), [server.observer()])
            mine, real = tree_part(ours.ask(header("T"))[1]), tree_part(theirs.ask(header("T"))[1])
            assert [t.get("_fullpath") for t in mine] == ["", "mid", "mid/Inner::4", "mid/again"]
            assert all(map(same_element, mine, real)) and len(mine) == len(real)
            assert ours.ask(header("S"))[1] == theirs.ask(header("S"))[1]
            names = b"Outer;mid;mid/Inner::4;mid/again"
            dump = msgpack.unpackb(ours.ask(header("B"), names)[1])
            assert dump == msgpack.unpackb(theirs.ask(header("B"), names)[1])
            assert dump["Outer"] == {"never": None}  # declared by the port, never written
        finally:
            ours.close()
            theirs.close()
    del publisher


def test_a_message_on_the_blackboard_is_sent_as_its_fields(registry):
    from geometry_msgs.msg import PoseStamped

    from runtime.app.groot2 import blackboard_dump

    loaded = load_tree(NESTED, registry, make_context(RunOptions()))
    pose = PoseStamped()
    pose.header.frame_id = "world"
    pose.pose.position.x = 0.5
    loaded.blackboard.set("goal", pose)
    dump = blackboard_dump(monitored_tree(loaded).blackboards, "Outer")
    assert dump["Outer"]["goal"]["header"]["frame_id"] == "world"
    assert dump["Outer"]["goal"]["pose"]["position"] == {"x": 0.5, "y": 0.0, "z": 0.0}
    assert msgpack.unpackb(msgpack.packb(dump)) == dump


# -- a client costs the tick loop a bounded share --------------------------------------------
@pytest.fixture
def ours(registry):
    """Our server showing XML's tree, and a client of it."""
    context = make_context(RunOptions())
    loaded = load_tree(XML, registry, context)
    server = Groot2Server(Groot2Options(port=0))
    server.show(loaded)
    client = Client(server.port)
    yield server, loaded, client
    client.close()
    server.close()


def test_a_request_frame_over_the_cap_is_never_read(ours):
    """A 1 MiB frame (the cap is 64 KiB) is dropped by ZeroMQ unread: no reply, no memory kept;
    other clients are served as before."""
    from runtime.app.groot2 import MAX_REQUEST_BYTES

    server, _, client = ours
    assert MAX_REQUEST_BYTES == 64 << 10
    client.socket.setsockopt(zmq.RCVTIMEO, 500)
    with pytest.raises(zmq.Again):
        client.ask(header("B"), b"Main;" * (1 << 18))
    other = Client(server.port)
    try:
        assert other.ask(header("S"))[0][:6] == header("S")
    finally:
        other.close()


def test_a_blackboard_request_and_its_reply_are_bounded(registry):
    from runtime.app.groot2 import MonitorLimits

    context = make_context(RunOptions())
    loaded = load_tree(XML, registry, context)
    tick_tree(loaded.root)
    with Groot2Server(Groot2Options(port=0, limits=MonitorLimits(max_reply_bytes=10))) as server:
        server.show(loaded)
        client = Client(server.port)
        try:
            names = ";".join(f"board{k}" for k in range(300)).encode()
            assert client.ask(header("B"), names) == [
                b"error", b"a blackboard request names at most 256 blackboards, got 300"]
            reply = client.ask(header("B"), b"Main;" * 10000)  # one blackboard, asked 10,000 times: once
            assert reply[0] == b"error" and reply[1].startswith(b"the blackboards asked for take ")
            assert reply[1].endswith(b" bytes, over the 10 a reply may have: ask for fewer")
        finally:
            client.close()


def test_the_tick_never_waits_for_an_answer_being_computed(ours, monkeypatch):
    """While the server thread computes an answer (a blackboard dump held here until released),
    the tick side's ``update`` takes the new statuses at once."""
    import threading

    import runtime.app.groot2 as groot2

    server, loaded, client = ours
    entered, release = threading.Event(), threading.Event()
    dump = groot2.blackboard_dump

    def slow_dump(*args: Any) -> Any:
        entered.set()
        release.wait(10.0)
        return dump(*args)

    monkeypatch.setattr(groot2, "blackboard_dump", slow_dump)
    asking = threading.Thread(target=client.ask, args=(header("B"), b"Main"), daemon=True)
    asking.start()
    try:
        assert entered.wait(5.0), "the server never started the answer"
        tick = tick_tree(loaded.root)
        updating = threading.Thread(target=server.update, args=(tick.visited,), daemon=True)
        updating.start()
        updating.join(5.0)
        assert not updating.is_alive(), "update() waited for the monitor's answer"
    finally:
        release.set()
        asking.join(5.0)


def test_the_server_rests_so_that_it_works_at_most_its_share(ours, monkeypatch):
    import runtime.app.groot2 as groot2

    assert groot2.rest_after(0.01, 0.1) == pytest.approx(0.09)  # 10 ms of work in 100 ms: a tenth
    rests: list[tuple[float, float]] = []
    monkeypatch.setattr(groot2, "rest_after", lambda busy_s, share: rests.append((busy_s, share)) or 0.0)
    server, _, client = ours
    for _ in range(5):
        client.ask(header("S"))
    assert len(rests) >= 4 and all(share == groot2.MAX_SHARE == 0.1 for _, share in rests)
