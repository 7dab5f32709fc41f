"""Fuzzing the Objective loader: whatever the XML, loading ends in success or a clean bad-input
error (``ObjectiveError``, exit code 2 in the CLI) within a bound: never another exception (a
traceback), never a hang, never a file read it was not asked to read.

Inputs: the shipped Objectives mutated at random (deleted, duplicated and inserted spans,
XML-ish tokens, control characters, invalid UTF-8, truncation), deep nesting, huge attributes and
files, entity bombs, external entities, XInclude, a DOCTYPE hidden after a BOM, and absurd
numbers (inf, nan, 1e309, 1e-300, a billion, a 5000-digit integer) in every numeric port of every
registered node.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.tree.behavior import NodeKind
from runtime.errors import ObjectiveError
from runtime.tree.loader import load_tree
from runtime.tree.ports import MESSAGE_CLASSES, NUMERIC_TYPES, Direction, PortInfo, PortType, Range, convert, range_problem
from runtime.tree.registry import NodeSpec, Registry
from runtime.app.runner import RunOptions, make_context

ROOT = Path(__file__).resolve().parent.parent
SEEDS = sorted((ROOT / "objectives").rglob("*.xml"))
TOKENS = [
    "<", ">", "/>", "</", '"', "'", "=", "&", "&amp;", "&lt;", "&#0;", "&#x110000;", "&#65;", "&undefined;",
    "<Sequence>", "</Sequence>", "<Fallback>", "<SubTree ID=\"Move to Waypoint\"/>", "<SubTree ID=\"Missing\"/>",
    "<Action ID=\"\"/>", "<Decorator ID=\"Inverter\">", "<Control ID=\"Parallel\" success_count=\"-1\">",
    "<BehaviorTree ID=\"T\">", "</BehaviorTree>", "<root>", "</root>", "<TreeNodesModel>", "<include path=\"/etc/passwd\"/>",
    "<!-- c -->", "<![CDATA[x]]>", "<?pi x?>", "<!DOCTYPE r>", "<!ENTITY e \"x\">", "{", "}", "{=}", "{@a}", "{a}",
    "_autoremap=\"maybe\"", "_skipIf=\"a ==\"", "_while=\"(((\"", "_onSuccess=\"x := 1/0\"", " ID=\"", " name=\"\"",
    "msec=\"-5\"", "num_cycles=\"1e309\"", "seconds=\"nan\"", "total_action_steps=\"-1\"", "dt=\"0\"",
    "\x00", "\x01", "\ufeff", "\u202e", "\U0001f916", "\udcff",
]
BOUND_S = 60  # per test (pytest-timeout): a hang fails, never blocks the suite


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def load_file(path: Path, registry: Registry) -> None:
    """Load like ``objective validate``; only ObjectiveError may escape."""
    load_tree(path, registry, make_context(RunOptions()))


@st.composite
def mutated(draw) -> bytes:
    data = SEEDS[draw(st.integers(0, len(SEEDS) - 1))].read_bytes()
    for _ in range(draw(st.integers(1, 6))):
        n = len(data)
        at = draw(st.integers(0, max(n - 1, 0)))
        op = draw(st.sampled_from(["delete", "duplicate", "insert", "bytes", "truncate", "swap"]))
        span = draw(st.integers(1, 40))
        if op == "delete":
            data = data[:at] + data[at + span:]
        elif op == "duplicate":
            data = data[:at] + data[at:at + span] * draw(st.integers(2, 50)) + data[at:]
        elif op == "insert":
            token = draw(st.sampled_from(TOKENS)).encode("utf-8", "surrogatepass")
            data = data[:at] + token + data[at:]
        elif op == "bytes":
            data = data[:at] + draw(st.binary(min_size=1, max_size=8)) + data[at:]
        elif op == "truncate":
            data = data[:at]
        else:
            other = draw(st.integers(0, max(n - 1, 0)))
            a, b = sorted((at, other))
            data = data[:a] + data[b:b + span] + data[a + span:b] + data[a:a + span] + data[b + span:]
    return data


@pytest.mark.timeout(3 * BOUND_S)  # 80 loads: a hang in any of them still fails the test
@settings(max_examples=80, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=mutated())
def test_mutated_objectives_load_or_fail_cleanly(registry, data):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mutated.xml"
        path.write_bytes(data)
        try:
            load_file(path, registry)
        except ObjectiveError as err:
            assert str(err).strip(), "an error must say what is wrong"


def nested(depth: int) -> str:
    return ('<root BTCPP_format="4"><BehaviorTree ID="T">' + "<Sequence>" * depth + "<AlwaysSuccess/>"
            + "</Sequence>" * depth + "</BehaviorTree></root>")


BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE root [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
 <!ENTITY lol5 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
 <!ENTITY lol6 "&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;">
 <!ENTITY lol7 "&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;">
 <!ENTITY lol8 "&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;">
 <!ENTITY lol9 "&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;">
]>
<root BTCPP_format="4"><BehaviorTree ID="T"><Script code="x := '&lol9;'"/></BehaviorTree></root>"""

QUADRATIC_BLOWUP = ('<?xml version="1.0"?><!DOCTYPE root [<!ENTITY a "' + "x" * 50000 + '">]>'
                    '<root BTCPP_format="4"><BehaviorTree ID="T"><Script code="' + "&a;" * 50000 + '"/></BehaviorTree></root>')


def external_entity(target: Path) -> str:
    return (f'<?xml version="1.0"?><!DOCTYPE root [<!ENTITY ext SYSTEM "file://{target}">]>'
            '<root BTCPP_format="4"><BehaviorTree ID="T"><Script code="x := \'&ext;\'"/></BehaviorTree></root>')


def parameter_entity(target: Path) -> str:
    return (f'<?xml version="1.0"?><!DOCTYPE root [<!ENTITY % p SYSTEM "file://{target}"> %p;]>'
            '<root BTCPP_format="4"><BehaviorTree ID="T"><AlwaysSuccess/></BehaviorTree></root>')


def external_dtd(target: Path) -> str:
    return (f'<?xml version="1.0"?><!DOCTYPE root SYSTEM "file://{target}">'
            '<root BTCPP_format="4"><BehaviorTree ID="T"><AlwaysSuccess/></BehaviorTree></root>')


def xinclude(target: Path) -> str:
    return ('<root BTCPP_format="4" xmlns:xi="http://www.w3.org/2001/XInclude"><BehaviorTree ID="T">'
            f'<Sequence><xi:include href="file://{target}" parse="text"/><AlwaysSuccess/></Sequence></BehaviorTree></root>')


NASTY = {
    "deep_nesting": lambda t: nested(100_000),
    "just_past_the_depth_limit": lambda t: nested(210),
    "huge_attribute": lambda t: '<root BTCPP_format="4"><BehaviorTree ID="T"><Script code="' + "x" * 4_000_000 + '"/></BehaviorTree></root>',
    "huge_file": lambda t: "<root>" + "<!-- padding -->" * 400_000 + "</root>",
    "many_attributes": lambda t: '<root BTCPP_format="4"><BehaviorTree ID="T"><AlwaysSuccess ' + " ".join(f'a{i}="1"' for i in range(100_000)) + "/></BehaviorTree></root>",
    "wide_tree": lambda t: '<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>' + "<AlwaysSuccess/>" * 100_000 + "</Sequence></BehaviorTree></root>",
    "billion_laughs": lambda t: BILLION_LAUGHS,
    "quadratic_blowup": lambda t: QUADRATIC_BLOWUP,
    "external_entity": external_entity,
    "parameter_entity": parameter_entity,
    "external_dtd": external_dtd,
    "xinclude": xinclude,
    "doctype_after_bom": lambda t: "\ufeff" + BILLION_LAUGHS.split("\n", 1)[1],
    "subtree_recursion": lambda t: '<root BTCPP_format="4"><BehaviorTree ID="T"><SubTree ID="T"/></BehaviorTree></root>',
    "subtree_fanout": lambda t: "<root BTCPP_format=\"4\" main_tree_to_execute=\"L0\">" + "".join(
        f'<BehaviorTree ID="L{i}"><Sequence>' + f'<SubTree ID="L{i + 1}"/>' * 4 + "</Sequence></BehaviorTree>" for i in range(12)
    ) + '<BehaviorTree ID="L12"><AlwaysSuccess/></BehaviorTree></root>',
    "subtree_chain": lambda t: '<root BTCPP_format="4" main_tree_to_execute="C0">' + "".join(
        f'<BehaviorTree ID="C{i}"><SubTree ID="C{i + 1}"/></BehaviorTree>' for i in range(500)
    ) + '<BehaviorTree ID="C500"><AlwaysSuccess/></BehaviorTree></root>',
}


class ReadWatch:
    """Does anyone open ``path`` for reading while we watch? ``path`` is a FIFO: opening it for
    writing without blocking only succeeds while a reader holds it open, and a reader that opened
    it waits for a writer, so a loader reading it would also show up as a hang."""

    def __init__(self, path: Path) -> None:
        os.mkfifo(path)
        self.path, self.seen = path, False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)

    def _watch(self) -> None:
        while not self._stop.is_set():
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:
                self._stop.wait(0.001)
                continue
            self.seen = True
            os.write(fd, b"SECRET-CANARY")
            os.close(fd)

    def __enter__(self) -> ReadWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(1.0)


@pytest.mark.timeout(BOUND_S)
@pytest.mark.parametrize("case", sorted(NASTY))
def test_hostile_objective_is_refused_cleanly_without_reading_files(registry, tmp_path, case):
    path = tmp_path / f"{case}.xml"
    path.write_text(NASTY[case](tmp_path / "canary"), encoding="utf-8", errors="surrogatepass")
    with ReadWatch(tmp_path / "canary") as watch:
        loaded = threading.Event()
        outcome: list[BaseException | None] = []

        def load() -> None:
            try:
                load_file(path, registry)
                outcome.append(None)
            except BaseException as err:  # noqa: BLE001 (the test inspects whatever escaped)
                outcome.append(err)
            loaded.set()

        worker = threading.Thread(target=load, daemon=True)
        worker.start()
        assert loaded.wait(BOUND_S - 10), f"{case}: loading did not finish (a hang)"
    assert not watch.seen, f"{case}: the loader opened a file the Objective pointed at"
    error = outcome[0]
    if case == "wide_tree":
        assert error is None or isinstance(error, ObjectiveError), repr(error)
        return
    assert isinstance(error, ObjectiveError), f"{case}: expected a clean ObjectiveError, got {error!r}"
    assert "SECRET-CANARY" not in str(error)
    assert str(error).startswith(str(path.name)) or str(path) in str(error) or path.name in str(error)


EXPECTED = {
    "billion_laughs": "DOCTYPE and entity declarations are not allowed in Objectives",
    "external_entity": "DOCTYPE and entity declarations are not allowed in Objectives",
    "parameter_entity": "DOCTYPE and entity declarations are not allowed in Objectives",
    "external_dtd": "DOCTYPE and entity declarations are not allowed in Objectives",
    "huge_attribute": "attribute 'code' is 4000000 characters long (limit 65536)",
    "huge_file": "Objectives are limited to 5242880 bytes",
    "just_past_the_depth_limit": "elements nest deeper than 200 levels",
    "many_attributes": "<AlwaysSuccess> has 100000 attributes (limit 1000)",
    "subtree_chain": "the tree nests more than 150 nodes deep after expanding SubTrees (151 trees deep: C0 -> C1 -> C2 -> ...",
}


@pytest.mark.timeout(BOUND_S)
@pytest.mark.parametrize("case", sorted(EXPECTED))
def test_refusals_say_what_was_refused(registry, tmp_path, case):
    path = tmp_path / f"{case}.xml"
    path.write_text(NASTY[case](tmp_path / "absent"), encoding="utf-8")
    with pytest.raises(ObjectiveError) as err:
        load_file(path, registry)
    assert EXPECTED[case] in str(err.value)


@pytest.mark.timeout(BOUND_S)
def test_cli_exits_2_without_a_traceback_on_hostile_files(tmp_path):
    files = []
    for case in ("deep_nesting", "billion_laughs", "external_entity", "huge_attribute", "xinclude", "subtree_recursion", "subtree_chain"):
        path = tmp_path / f"{case}.xml"
        path.write_text(NASTY[case](tmp_path / "absent"), encoding="utf-8")
        files.append(str(path))
    (tmp_path / "binary.xml").write_bytes(bytes(range(256)) * 8)
    files.append(str(tmp_path / "binary.xml"))
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    proc = subprocess.run([sys.executable, "-m", "runtime.app.cli", "validate", *files], capture_output=True, text=True,
                          timeout=BOUND_S - 5, cwd=ROOT, env=env)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout
    for f in files:
        assert Path(f).name in proc.stderr, f"no error reported for {f}:\n{proc.stderr}"


# -- absurd numbers in every numeric port of every registered node ----------------------------
# Generated from the registry (the installed behaviors included), so a new behavior is covered
# the day it is registered: `objective validate` accepts each value, or exits 2 naming the port.
ABSURD = [
    "inf", "-inf", "nan", "NaN", "1e309", "-1e309", "1e-300", "-1e-300", "1e300", "-1e300", "-1", "0", "-0",
    "1000000000", "99999999999999999999999999", "1" + "0" * 5000, "0x7fffffffffffffff", "4.5", "1e-3",
    "nan;1;1;1;1;1", "1;1;1;1;1;inf", "1e309;45;45;10;10;10", "-1;-1;-1;-1;-1;-1", "1e300;1e300;1e300;1e300;1e300;1e300",
    "٣٠", "３０", "1_000", "1;1;1;1;1;１",
]
NON_FINITE = {"inf", "-inf", "nan", "NaN", "1e309", "-1e309"}
NOT_PLAIN_NUMBERS = {"٣٠", "３０", "1_000", "1;1;1;1;1;１"}
"""Digits Python reads but BT.CPP does not (non-ASCII digits, underscores): always refused."""


def _registered() -> Registry:
    return Registry.from_entry_points()


def _numeric_ports() -> list[tuple[str, str]]:
    return [
        (spec.id, port.name)
        for spec in _registered().specs()
        if spec.kind is not NodeKind.SUBTREE
        for port in spec.cls.ports
        if port.type in NUMERIC_TYPES and port.direction is not Direction.OUTPUT
    ]


def _in_range(port: PortInfo) -> str:
    """A value the port accepts, for the ports a case leaves alone."""
    if port.type not in NUMERIC_TYPES:
        entry = f"{{{port.name}_entry}}"  # one entry per port: BT.CPP refuses one entry with two types
        literal = {PortType.BOOL: "false", PortType.ANY: entry, PortType.STRING_LIST: "a"}.get(port.type, "x")
        # message and vector ports take blackboard entries only
        return entry if port.type in MESSAGE_CLASSES or port.type in (PortType.POSE_STAMPED_LIST, PortType.ANY_LIST) else literal
    valid = port.valid or Range()
    low, high = valid.min, valid.max
    middle = 0.0 if low is None and high is None else (low if high is None else high if low is None else (low + high) / 2)
    value = str(int(middle)) if port.type in (PortType.INT, PortType.UINT, PortType.INT_LIST) else repr(float(middle))
    return ";".join([value] * (port.length or 6)) if port.type in (PortType.FLOAT_LIST, PortType.INT_LIST) else value


def _one_node_tree(spec: NodeSpec, values: dict[str, str]) -> str:
    attrs = " ".join(f'{name}="{value}"' for name, value in values.items())
    children = {NodeKind.CONTROL: "<AlwaysSuccess/><AlwaysSuccess/>", NodeKind.DECORATOR: "<AlwaysSuccess/>"}.get(spec.kind, "")
    node = f"<{spec.id} {attrs}>{children}</{spec.id}>"
    return f'<root BTCPP_format="4">\n<BehaviorTree ID="T">\n{node}\n</BehaviorTree>\n</root>\n'


@pytest.fixture(scope="module")
def validate_cli(registry):
    from runtime.app.cli import main

    def run(path: Path, capsys) -> tuple[int, str, str]:
        code = main(["validate", str(path)], registry=registry)
        out, err = capsys.readouterr()
        return code, out, err

    return run


@pytest.mark.timeout(BOUND_S)
@pytest.mark.parametrize("node_id,port_name", _numeric_ports())
def test_absurd_numbers_in_every_numeric_port_are_accepted_or_refused_by_name(registry, validate_cli, tmp_path,
                                                                              capsys, node_id, port_name):
    spec = registry.get(node_id)
    port = spec.cls.port_info()[port_name]
    required = {p.name: _in_range(p) for p in spec.cls.ports if p.required}
    path = tmp_path / "t.xml"
    path.write_text(_one_node_tree(spec, required))
    code, _, err = validate_cli(path, capsys)
    assert code == 0, f"the case's baseline does not load: {err}"
    for value in ABSURD:
        path.write_text(_one_node_tree(spec, {**required, port_name: value}))
        code, out, err = validate_cli(path, capsys)
        assert "Traceback" not in err + out
        assert code in (0, 2), (value, err)
        if code == 2:
            assert f"{path}:3: {node_id}: port '{port_name}' " in err, (value, err)
        else:  # accepted: then it is a value the port's declared range allows
            assert range_problem(port, convert(value, port.type)) is None, value
        if port.type in (PortType.FLOAT, PortType.FLOAT_LIST) and any(v in NON_FINITE for v in value.split(";")):
            assert code == 2, f"{node_id}.{port_name} accepted {value!r}"
        if value in NOT_PLAIN_NUMBERS:
            assert code == 2, f"{node_id}.{port_name} accepted {value!r}"


def test_every_numeric_port_declares_its_range_and_its_default_is_in_it():
    """Shown by `objective behaviors` and `objective models`; a new behavior must declare its own."""
    for spec in _registered().specs():
        for port in spec.cls.ports:
            if port.type not in NUMERIC_TYPES or port.direction is Direction.OUTPUT:
                continue
            assert port.valid is not None, (
                f"{spec.id}.{port.name} ({port.type.value}) declares no valid range: "
                "give it InputPort(..., valid=Range(min, max, unit)) (see docs/extending.md)"
            )
            if not port.required:
                default = convert(port.default, port.type) if isinstance(port.default, str) else port.default
                assert range_problem(port, default) is None, f"{spec.id}.{port.name}: default {port.default!r} is outside {port.valid}"
