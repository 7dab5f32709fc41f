"""The `objective` command: exit codes, the --json last line, validate, behaviors, show, models."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree

from runtime.app.cli import main
from runtime.tree.loader import display_path
from tests.data.nodes import make_registry
from tools.cli_synopsis import synopsis

REPO = Path(__file__).resolve().parent.parent
DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def registry():
    return make_registry()


@pytest.fixture
def lib(tmp_path):
    path = tmp_path / "lib"
    path.mkdir()
    return path


@pytest.fixture
def cli(registry, lib, capsys):
    def _cli(*argv: str) -> tuple[int, str, str]:
        args = list(argv)
        if args[0] in ("run", "validate", "show"):
            args += ["--objectives-dir", str(lib)]
        code = main(args, registry=registry)
        out, err = capsys.readouterr()
        return code, out, err

    return _cli


def tree_file(tmp_path: Path, body: str, name: str = "t.xml") -> Path:
    path = tmp_path / name
    path.write_text(f'<root BTCPP_format="4">\n  <BehaviorTree ID="T">\n    {body}\n  </BehaviorTree>\n</root>\n')
    return path


def test_run_success_exit_0_and_json_last_line(cli, tmp_path):
    path = tree_file(tmp_path, '<Sequence><Wait seconds="0.1"/><Typed x="{x}" out="{y}"/></Sequence>')
    code, out, err = cli("run", str(path), "--json", "--set", "x=2", "--seed", "3")
    assert code == 0
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["status"] == "SUCCESS"
    assert summary["failing_node"] is None and summary["reason"] == ""
    assert summary["ticks"] == 11 and summary["sim_seconds"] == pytest.approx(0.11)
    assert summary["blackboard"] == {"x": "2", "y": 6.0}
    assert set(summary) >= {"status", "failing_node", "reason", "sim_seconds", "wall_seconds", "ticks", "blackboard"}
    assert "SUCCESS after 0.11 s (11 ticks)" in err


def test_run_failure_exit_1_names_the_node_and_reason(cli, tmp_path):
    path = tree_file(tmp_path, '<Sequence><LogMessage message="starting"/><FailWith name="grasp" reason="cube slipped"/></Sequence>')
    code, out, err = cli("run", str(path), "--json")
    assert code == 1
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["status"], summary["failing_node"], summary["reason"]) == ("FAILURE", "grasp", "cube slipped")
    assert f"FAILURE after 0.01 s: 'grasp' ({path}:3) failed: cube slipped" in err
    assert "[INFO] starting" in err


def test_run_without_json_prints_nothing_on_stdout(cli, tmp_path):
    code, out, _ = cli("run", str(tree_file(tmp_path, "<AlwaysSuccess/>")))
    assert (code, out) == (0, "")


def test_run_bad_input_exit_2_without_traceback(cli, tmp_path):
    path = tree_file(tmp_path, '<Typed x="fast"/>')
    code, out, err = cli("run", str(path))
    assert code == 2
    assert err == f"error: {path}:3: Typed: port 'x' expects a number, got 'fast'\n"
    assert out == ""
    code, out, err = cli("run", str(path), "--json")
    assert json.loads(out.strip().splitlines()[-1]) == {
        "status": "ERROR", "reason": f"{path}:3: Typed: port 'x' expects a number, got 'fast'", "failure_kind": "PortError",
    }


def test_policy_latency_trace_replays_each_call_and_repeats_the_last(tmp_path):
    """Pins ``--policy-latency trace:FILE``: call i takes line i (the warmup is the first call),
    blank lines and # comments are skipped, and the last value repeats."""
    from runtime.io.bus import parse_latency

    trace = tmp_path / "robot latencies.txt"
    trace.write_text("# measured on the robot\n0.4\n\n0.05  # a fast one\n3\n0.1\n")
    model = parse_latency(f"trace:{trace}")
    assert [model.delay(0.0) for _ in range(6)] == [0.4, 0.05, 3.0, 0.1, 0.1, 0.1]
    assert repr(model) == f"trace:{trace}"


@pytest.mark.parametrize(
    "content, problem",
    [
        (None, "cannot be read: No such file or directory"),
        ("", "is empty: it needs one latency in seconds per line"),
        ("# only a comment\n\n", "is empty: it needs one latency in seconds per line"),
        ("0.1\nfast\n", ":2: 'fast' is not a number of seconds"),
        ("0.1\n0.2\n-0.3\n", ":3: a latency must be a finite number of seconds >= 0, got '-0.3'"),
        ("nan\n", ":1: a latency must be a finite number of seconds >= 0, got 'nan'"),
        ("0.1\ninf\n", ":2: a latency must be a finite number of seconds >= 0, got 'inf'"),
    ],
    ids=["missing", "empty", "comments-only", "non-numeric", "negative", "nan", "inf"],
)
def test_a_bad_latency_trace_is_bad_input_before_anything_runs(cli, tmp_path, content, problem):
    trace = tmp_path / "trace.txt"
    if content is not None:
        trace.write_text(content)
    path = tree_file(tmp_path, "<AlwaysSuccess/>")
    code, out, err = cli("run", str(path), "--policy-latency", f"trace:{trace}", "--json")
    assert code == 2
    assert "--policy-latency: " in err and problem in err and "Traceback" not in err
    assert str(trace) in err
    assert json.loads(out.strip().splitlines()[-1])["status"] == "ERROR"


def test_an_endless_latency_trace_is_refused_after_10_million_characters(cli, tmp_path):
    """``trace:/dev/zero`` is read up to the bound, never without end."""
    path = tree_file(tmp_path, "<AlwaysSuccess/>")
    code, out, err = cli("run", str(path), "--policy-latency", "trace:/dev/zero", "--json")
    assert code == 2
    assert "--policy-latency: latency trace '/dev/zero' holds more than 10,000,000 characters" in err


def test_run_missing_file_and_bad_options_exit_2(cli, tmp_path):
    code, _, err = cli("run", str(tmp_path / "nope.xml"))
    assert code == 2 and "nope.xml: cannot read file: No such file or directory" in err
    path = tree_file(tmp_path, "<AlwaysSuccess/>")
    code, _, err = cli("run", str(path), "--policy-latency", "soon")
    assert code == 2 and "--policy-latency: latency 'soon'" in err
    with pytest.raises(SystemExit) as info:
        cli("run", str(path), "--set", "novalue")
    assert info.value.code == 2


def test_run_tree_option_and_search_path(cli, tmp_path):
    extra = tmp_path / "extra"
    extra.mkdir()
    (extra / "lib.xml").write_text('<root BTCPP_format="4"><BehaviorTree ID="Far"><Script code="far := 1"/></BehaviorTree></root>')
    path = tmp_path / "two.xml"
    path.write_text("""<root BTCPP_format="4">
  <BehaviorTree ID="A"><AlwaysFailure/></BehaviorTree>
  <BehaviorTree ID="B"><SubTree ID="Far" _autoremap="true"/></BehaviorTree>
</root>""")
    code, _, err = cli("run", str(path))
    assert code == 2 and "several BehaviorTrees (A, B)" in err
    code, out, _ = cli("run", str(path), "--tree", "B", "--path", str(extra), "--json")
    assert code == 0 and json.loads(out.splitlines()[-1])["blackboard"] == {"far": 1}


def test_run_max_seconds(cli, tmp_path):
    code, out, err = cli("run", str(tree_file(tmp_path, '<Forever name="spin"/>')), "--max-seconds", "0.5", "--json")
    assert code == 1
    assert json.loads(out.splitlines()[-1])["reason"] == (
        "stopped after --max-seconds 0.5 s of clock time while 'spin' was RUNNING"
    )


def test_validate_lists_each_error_and_exits_2(cli, tmp_path):
    good = tree_file(tmp_path, "<AlwaysSuccess/>", "good.xml")
    bad_port = tree_file(tmp_path, '<Typed x="1" y="2"/>', "bad_port.xml")
    bad_node = tree_file(tmp_path, "<Sequense><AlwaysSuccess/></Sequense>", "bad_node.xml")
    code, out, err = cli("validate", str(good), str(bad_port), str(bad_node))
    assert code == 2
    assert out == f"ok: {good}: T (1 nodes)\n"
    assert err.splitlines() == [
        f"error: {bad_port}:3: Typed: unknown port 'y' (ports: flag, n, out, x)",
        f"error: {bad_node}:3: Sequense: unknown node 'Sequense'; did you mean 'Sequence' or 'AsyncSequence'?",
    ]
    code, out, _ = cli("validate", str(good), str(DATA / "subtrees.xml"))
    assert code == 0
    assert out.splitlines()[1] == f"ok: {DATA / 'subtrees.xml'}: Main (5 nodes), Greet (1 nodes)"


def test_behaviors_json_lists_ports_with_types_defaults_and_descriptions(cli):
    code, out, _ = cli("behaviors", "--json")
    assert code == 0
    nodes = {n["id"]: n for n in json.loads(out)}
    assert nodes["Typed"]["kind"] == "Action"
    assert nodes["Typed"]["description"] == "Writes x * n to out."
    assert nodes["Typed"]["ports"] == [
        {"name": "x", "direction": "input", "type": "double", "default": None, "required": True, "description": "A number.",
         "valid": "[-1000000, 1000000]"},
        {"name": "n", "direction": "input", "type": "int", "default": "3", "required": False, "description": "How many times.",
         "valid": "[0, 100]"},
        {"name": "flag", "direction": "input", "type": "bool", "default": "false", "required": False, "description": "A switch.",
         "valid": None},
        {"name": "out", "direction": "output", "type": "double", "default": None, "required": False, "description": "x * n.",
         "valid": None},
    ]
    assert nodes["Sequence"]["kind"] == "Control" and nodes["Inverter"]["kind"] == "Decorator"
    wait = {p["name"]: p for p in nodes["Wait"]["ports"]}
    assert wait["seconds"]["valid"] == "[0, 4294967.295] s"
    code, out, _ = cli("behaviors")
    assert "Typed  [Action]" in out
    assert "      input  n (int, default '3', valid [0, 100]): How many times." in out
    assert "      input  seconds (double, required, valid [0, 4294967.295] s): How long to wait, in seconds." in out


def test_show_prints_the_tree_with_kinds_and_ports(cli):
    code, out, _ = cli("show", str(DATA / "subtrees.xml"))
    assert code == 0
    path = display_path(DATA / "subtrees.xml")  # relative to the working directory when inside it
    assert out.splitlines() == [
        "BehaviorTree Main",
        f'  Control Sequence  "TopLevelSequence"  ({path}:5)',
        f"    Action Script  code=\"who := 'world'\"  ({path}:6)",
        f"    SubTree Greet  name={{who}}  text={{greeting}}  prefix=hello  ({path}:7)",
        f"      Action Script  code=\"text := prefix .. ' ' .. name\"  ({path}:12)",
        f"    Condition ScriptCondition  code=\"greeting == 'hello world'\"  ({path}:8)",
    ]


def test_models_is_tree_nodes_model_xml(cli):
    code, out, _ = cli("models")
    assert code == 0
    root = etree.fromstring(out.encode())
    assert root.tag == "root" and root.get("BTCPP_format") == "4"
    typed = root.find("TreeNodesModel/Action[@ID='Typed']")
    ports = [(p.tag, p.get("name"), p.get("type"), p.get("default"), p.text) for p in typed if p.tag.endswith("_port")]
    assert ports == [
        ("input_port", "x", "double", None, "A number. (valid: [-1000000, 1000000])"),
        ("input_port", "n", "int", "3", "How many times. (valid: [0, 100])"),
        ("input_port", "flag", "bool", "false", "A switch."),
        ("output_port", "out", "double", None, "x * n."),
    ]
    assert root.find("TreeNodesModel/Control[@ID='Sequence']") is None  # BT.CPP built-ins are left out
    code, out, _ = cli("models", "--all")
    assert etree.fromstring(out.encode()).find("TreeNodesModel/Control[@ID='Sequence']") is not None


def test_models_xml_is_accepted_by_behaviortree_cpp(cli):
    import behaviortreepy  # a test dependency (pyproject's dev group): missing, the test fails
    _, out, _ = cli("models")
    behaviortreepy.BehaviorTreeFactory().register_behavior_tree_from_text(out)


def test_console_script_exit_codes(tmp_path):
    """The installed `objective` entry point, end to end (one subprocess per exit code)."""
    exe = Path(sys.executable).parent / "objective"
    assert exe.exists(), "the `objective` console script is missing: install the project (make setup)"
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    ok = tree_file(tmp_path, '<Sequence><Script code="n := 2"/><Wait seconds="0.05"/></Sequence>', "ok.xml")
    fail = tree_file(tmp_path, '<Fallback><AlwaysFailure name="a"/><Inverter name="b"><AlwaysSuccess/></Inverter></Fallback>', "fail.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text('<!DOCTYPE root [<!ENTITY x "y">]><root BTCPP_format="4"/>')
    results = {}
    for name, path in (("ok", ok), ("fail", fail), ("bad", bad)):
        proc = subprocess.run([str(exe), "run", str(path), "--json"], capture_output=True, text=True, env=env, timeout=120)
        results[name] = (proc.returncode, json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr)
    assert results["ok"][0] == 0 and results["ok"][1]["blackboard"] == {"n": 2}
    assert results["fail"][0] == 1 and results["fail"][1]["failing_node"] == "b"
    assert results["bad"][0] == 2 and "DOCTYPE and entity declarations are not allowed" in results["bad"][2]
    assert "Traceback" not in results["bad"][2]


def test_the_mujoco_cell_renders_without_mujoco_gl_set(tmp_path):
    """A user who never heard of MUJOCO_GL: the cameras still render (offscreen, EGL) instead of
    the run failing on an OpenGL context (seen before the CLI set the default)."""
    exe = Path(sys.executable).parent / "objective"
    assert exe.exists(), "the `objective` console script is missing: install the project (make setup)"
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    proc = subprocess.run([str(exe), "run", "objectives/stack_cubes.xml", "--max-seconds", "1.5", "--json",
                           "--policy-latency", "0.05"],  # measured latency (the default) made it load-dependent
                          capture_output=True, text=True, env=env, timeout=300, cwd=Path(__file__).resolve().parents[1])
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert proc.returncode == 1 and summary["reason"].startswith("stopped after --max-seconds 1.5 s"), proc.stderr
    assert summary["execute_policy"]["chunks"] >= 1  # the policy was asked, with rendered camera frames


# --------------------------------------------------------------------------------------------
# Commands and the default world come from entry points (the composition root's configuration)
# --------------------------------------------------------------------------------------------
def fake_entry_points(monkeypatch, module, groups: dict[str, list[tuple[str, str]]]):
    from importlib.metadata import EntryPoint

    def entry_points(group: str):
        return [EntryPoint(name, value, group) for name, value in groups.get(group, [])]

    monkeypatch.setattr(module, "entry_points", entry_points)


def test_installed_commands_come_from_the_entry_point_group(cli):
    code, out, _ = cli("serve", "--backend", "no-such-backend")
    assert code == 2
    code, _, err = cli("serve", "--backend", "no-such-backend", "--insecure-no-key")
    assert code == 2 and ("error: unknown backend 'no-such-backend' (known: lerobot, oracle, replay; "
                          "or your own factory as FILE.py:NAME or MODULE:NAME)") in err


def test_a_broken_or_clashing_command_is_left_out_with_a_warning(monkeypatch, cli):
    import runtime.app.cli

    fake_entry_points(monkeypatch, runtime.app.cli, {"objective.commands": [
        ("broken", "no_such_module_xyz:COMMAND"), ("run", "policy.commands:SERVE"),
        ("not-a-command", "runtime.app.cli:main"), ("smoke", "policy.commands:SMOKE_TEST"),
    ]})
    code, _, err = cli("smoke", "/s", "--joints", "a;a")
    assert code == 2 and "error: --joints names a joint twice: a;a" in err
    assert "warning: command 'broken' (no_such_module_xyz:COMMAND) failed to load: ModuleNotFoundError" in err
    assert "warning: command 'run' (policy.commands:SERVE) is defined twice; keeping the first" in err
    assert "warning: command 'not-a-command' (runtime.app.cli:main) is not a runtime.app.command.Command" in err


def test_the_engine_s_own_commands_load_no_installed_command(monkeypatch, cli, tmp_path, capsys):
    import runtime.app.cli

    fake_entry_points(monkeypatch, runtime.app.cli, {"objective.commands": [("broken", "no_such_module_xyz:COMMAND")]})
    code, out, err = cli("validate", str(tree_file(tmp_path, "<AlwaysSuccess/>")))
    assert code == 0 and "warning" not in err
    with pytest.raises(SystemExit):
        main(["--help"])  # lists every command: the installed ones are loaded
    assert "warning: command 'broken' (no_such_module_xyz:COMMAND) failed to load" in capsys.readouterr().err


def test_the_cyclic_collector_runs_again_once_the_installed_behaviors_are_loaded(tmp_path, lib, capsys):
    import gc

    objective = str(tree_file(tmp_path, "<AlwaysSuccess/>"))
    gc.unfreeze()
    assert main(["validate", objective, "--objectives-dir", str(lib)]) == 0
    assert gc.isenabled() and gc.get_freeze_count() > 0  # paused while they loaded, then frozen
    gc.disable()  # a caller's choice is kept
    try:
        assert main(["validate", objective, "--objectives-dir", str(lib)]) == 0
        assert not gc.isenabled()
    finally:
        gc.enable()


@pytest.mark.parametrize("defaults, message", [
    ([], "this tree needs a world and none is named: pass --world NAME (worlds: kinematic, vla_sim)"),
    ([("kinematic", "sim.kinematic:create_kinematic"), ("vla_sim", "sim.world:create_vla_sim")],
     "installed packages name 2 default worlds (kinematic, vla_sim): pass --world NAME (worlds: kinematic, vla_sim)"),
])
def test_the_default_world_is_the_installation_s_choice(monkeypatch, cli, tmp_path, defaults, message):
    import runtime.tree.registry

    fake_entry_points(monkeypatch, runtime.tree.registry, {
        "objective.default_world": defaults,
        "objective.worlds": [("vla_sim", "sim.world:create_vla_sim"), ("kinematic", "sim.kinematic:create_kinematic")],
    })
    code, _, err = cli("run", str(tree_file(tmp_path, "<Robot/>")))
    assert code == 2 and err.strip() == f"error: {message}"
    fake_entry_points(monkeypatch, runtime.tree.registry, {"objective.default_world": [("vla_sim", "sim.world:create_vla_sim")]})
    assert runtime.tree.registry.default_world_name() == "vla_sim"


# -- ends of a run other than SUCCESS/FAILURE, and what reaches the terminal ------------------
def test_run_ends_as_error_with_one_paragraph_and_the_traceback_in_a_log_file(cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the log goes to build/logs/ under the working directory
    path = tree_file(tmp_path, '<Parallel>\n<Wait seconds="10"/>\n<Crash name="probe" after="4"/>\n</Parallel>')
    code, out, err = cli("run", str(path), "--json")
    assert code == 2
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["status"], summary["failing_node"], summary["ticks"], summary["running_nodes"]) == ("ERROR", "probe", 5, ["Wait", "probe"])
    log = Path(summary["log_file"])
    assert log.parent == Path("build/logs") and "RuntimeError: sensor exploded" in (tmp_path / log).read_text()
    assert err == f"internal error: {summary['reason']}\n"  # a bug, never the user's mistake
    assert summary["failure_kind"] == "internal"
    assert summary["reason"].startswith("t.xml:5: Crash 'probe': an unexpected RuntimeError in ")
    assert summary["reason"].endswith(f"sensor exploded. The run was stopped and its running nodes halted; the full traceback is in {log} "
                                      "(a bug: please report it with that file)")


def test_a_bug_while_loading_names_the_node_and_exits_2(cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tree_file(tmp_path, "<Sequence>\n<BrokenAtLoad/>\n</Sequence>")
    code, out, err = cli("validate", str(path))
    assert (code, out) == (2, "")
    assert err.startswith(f"internal error: t.xml:4: BrokenAtLoad: an unexpected KeyError in {REPO / 'tests/data/nodes.py'}:")
    assert "'calibration'. Loading stopped there; nothing was run; the full traceback is in build/logs/objective-" in err
    assert "Traceback" not in err and len(list((tmp_path / "build" / "logs").glob("objective-*.log"))) == 1


def test_run_blackboard_value_outside_a_port_range_is_exit_2(cli, tmp_path):
    path = tree_file(tmp_path, '<Wait seconds="{s}"/>')
    code, out, err = cli("run", str(path), "--json", "--set", "s=nan")
    assert code == 2
    message = f"{path}:3: Wait: port 'seconds' (from '{{s}}') must be in [0, 4294967.295] s, got nan"
    assert err == f"error: {message}\n"
    assert json.loads(out.strip().splitlines()[-1])["reason"] == message


def test_validate_names_the_port_and_range_of_an_absurd_literal(cli, tmp_path):
    path = tree_file(tmp_path, '<Sequence>\n<Typed x="1e309"/>\n</Sequence>')
    code, out, err = cli("validate", str(path))
    assert (code, out) == (2, "")
    assert err == f"error: {path}:4: Typed: port 'x' must be in [-1000000, 1000000], got inf\n"


BIDI, ESC = "\u202e", "\x1b"


def test_control_and_bidi_characters_from_an_objective_are_escaped_everywhere(cli, tmp_path):
    """XML 1.0 allows U+202E, C1 controls (\\x9b is CSI on some terminals), CR and LF; --set allows ESC."""
    name = f"evil{BIDI}gpj.exe"
    path = tree_file(tmp_path, f'<Sequence name="{name}"><LogMessage message="{{m}}"/><LogMessage message="a&#13;b"/>'
                               f'<FailWith name="{name}" reason="csi\x9b2J&#10;next"/></Sequence>', f"t{BIDI}.xml")
    code, out, err = cli("run", str(path), "--set", f"m={ESC}[31mred")
    assert code == 1
    assert BIDI not in err and ESC not in err and "\x9b" not in err and "\r" not in err
    assert "[INFO] \\x1b[31mred\n" in err and "[INFO] a\\rb\n" in err
    assert "FAILURE after 0.01 s: 'evil\\u202egpj.exe' (" in err and "failed: csi\\x9b2J\\nnext" in err
    code, out, err = cli("validate", str(path))
    assert code == 0 and BIDI not in out and "t\\u202e.xml" in out
    code, out, err = cli("show", str(path))
    assert code == 0 and BIDI not in out and '"evil\\u202egpj.exe"' in out
    bad = tree_file(tmp_path, f'<Sequence name="{name}"><Typed x="nope"/></Sequence>', f"bad{BIDI}.xml")
    code, out, err = cli("run", str(bad), "--json")
    assert code == 2 and BIDI not in err and "bad\\u202e.xml:3: Typed: port 'x' expects a number" in err
    assert BIDI not in out  # JSON escapes it: \u202e


@pytest.mark.parametrize("separator", ["\u2028", "\u2029", "\x85"])
def test_a_line_separator_in_a_node_name_cannot_forge_a_line_of_objective_show(cli, tmp_path, separator):
    """On main `show` split its text with str.splitlines(), which also splits at U+2028, U+2029,
    NEL: a name could print a line of its own that looked like another node."""
    forged = f"a{separator}    Action AlwaysSuccess  (elsewhere.xml:1)"
    path = tree_file(tmp_path, f'<Sequence name="{forged}"><AlwaysSuccess/></Sequence>')
    code, out, err = cli("show", str(path))
    assert code == 0
    lines = out.rstrip("\n").split("\n")
    assert len(lines) == 3 and not any(line.lstrip().startswith("Action AlwaysSuccess  (elsewhere") for line in lines)
    escaped = {"\u2028": "\\u2028", "\u2029": "\\u2029", "\x85": "\\x85"}[separator]
    assert f'"a{escaped}    Action AlwaysSuccess  (elsewhere.xml:1)"' in lines[1]


def test_printable_escapes_only_what_a_terminal_would_act_on():
    from runtime.app.terminal import printable

    assert printable("Pick 'cube' ü → 機器人 🤖") == "Pick 'cube' ü → 機器人 🤖"
    assert printable(f"a{BIDI}b\u2066c\u200bd\r\n\te{ESC}\x85\u2028") == "a\\u202eb\\u2066c\\u200bd\\r\\n\\te\\x1b\\x85\\u2028"
    assert printable("a" * 5000) == "a" * 4096 + "... (904 characters cut)"  # a policy's 5 MB message too
    assert printable(ESC * 5000) == "\\x1b" * 4096 + "... (904 characters cut)"


def test_the_synopsis_in_docs_cli_md_is_the_argument_parser_s():
    """Every command and every option the parser takes is on the page, and nothing else
    (regenerate it with tools/cli_synopsis.py)."""
    page = (REPO / "docs" / "cli.md").read_text(encoding="utf-8")
    block = page.split("```\n", 2)[1].split("```", 1)[0]
    assert block.rstrip("\n") == synopsis()
    for option in ("--ros", "--policy SPEC", "--world-option KEY=VALUE", "objective report DIR"):
        assert option in block


def test_version_prints_the_installed_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out == f"objective {version('objective-runtime')}\n"


@pytest.mark.parametrize("command", ["run", "eval", "server"])
def test_the_policy_option_s_help_lists_every_form_the_spec_parser_takes(command):
    """``run --help`` listed "oracle (default), replay:FILE or none"; FILE.py:NAME, http(s):// and
    lerobot:DIR worked too."""
    from runtime.app.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    policy = next(a for a in sub._actions if "--policy" in a.option_strings)
    help_text = " ".join(policy.help.split())
    for form in ("oracle", "replay:FILE", "lerobot:DIR", "FILE.py:FACTORY", "MODULE:FACTORY", "http(s)://HOST:PORT", "none"):
        assert form in help_text, form


def test_every_positional_argument_has_help():
    from runtime.app.cli import build_parser

    parser = build_parser()
    for name, sub in next(a for a in parser._actions if a.dest == "command").choices.items():
        for action in sub._actions:
            if not action.option_strings:
                assert action.help, f"objective {name}: {action.dest} has no help"

