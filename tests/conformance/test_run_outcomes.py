"""How `objective run` ends on BT.CPP's edge cases: endless loops, a skipped root, script errors.

Loops: no node loops inside a tick (see ``runtime.tree.controls``), so an endless synchronous loop is
one iteration per tick and a Timeout, a ``_while``, a Parallel sibling, ``--max-seconds`` or a
signal can stop it. These run in a subprocess with a wall-clock bound: a regression fails the
test instead of hanging the suite.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.tree.behavior import Status
from runtime.app.cli import main
from runtime.tree.loader import load_tree
from runtime.app.runner import RunOptions, make_context, run_tree
from tests.data.nodes import Forever, make_registry

LOOP_BOUND_S = 60
"""Wall-clock bound of each subprocess; each run needs well under a second of CPU."""


@pytest.fixture(scope="module")
def registry():
    return make_registry()


def tree_file(tmp_path: Path, body: str, name: str = "t.xml") -> Path:
    path = tmp_path / name
    path.write_text(f'<root BTCPP_format="4">\n  <BehaviorTree ID="T">\n    {body}\n  </BehaviorTree>\n</root>\n')
    return path


def run_cli(tmp_path: Path, body: str, *args: str) -> tuple[int, dict, str]:
    """`python -m runtime.app.cli run FILE --json` in a subprocess, killed after LOOP_BOUND_S."""
    lib = tmp_path / "lib"
    lib.mkdir(exist_ok=True)
    path = tree_file(tmp_path, body)
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    code = (
        "import sys; from runtime.app.cli import main; from tests.data.nodes import make_registry; "
        "sys.exit(main(sys.argv[1:], registry=make_registry()))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, "run", str(path), "--json", "--objectives-dir", str(lib), *args],
        capture_output=True, text=True, env=env, timeout=LOOP_BOUND_S, cwd=Path(__file__).resolve().parents[2],
    )
    return proc.returncode, json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr


ENDLESS = '<Repeat num_cycles="-1"><Script code="n += 1"/></Repeat>'


@pytest.mark.parametrize(
    "body, status, n",
    [
        # A Timeout halts the endless loop after 50 ms: one cycle per 10 ms tick (t = 0.01 ... 0.05 s).
        (f'<Sequence><Script code="n := 0"/><Timeout msec="50">{ENDLESS}</Timeout></Sequence>', "FAILURE", 5),
        # _while turns false: the loop is halted and skipped, the Sequence goes on.
        ('<Sequence><Script code="n := 0"/><Repeat num_cycles="-1" _while="n &lt; 7"><Script code="n += 1"/></Repeat>'
         '<AlwaysSuccess/></Sequence>', "SUCCESS", 7),
        # A Parallel sibling finishes first (its 30 ms end at the 4th tick) and the loop is halted.
        (f'<Sequence><Script code="n := 0"/><Parallel success_count="1">{ENDLESS}<Sleep msec="30"/></Parallel></Sequence>',
         "SUCCESS", 4),
        # RetryUntilSuccessful forever over a synchronous failure, stopped by its _while.
        ('<Sequence><Script code="n := 0"/><RetryUntilSuccessful num_attempts="-1" _while="n &lt; 5">'
         '<ScriptCondition code="n += 1; false"/></RetryUntilSuccessful><AlwaysSuccess/></Sequence>', "SUCCESS", 5),
    ],
    ids=["timeout", "while", "parallel", "retry_forever"],
)
def test_endless_loops_yield_every_tick_and_can_be_stopped(tmp_path, body, status, n) -> None:
    code, summary, err = run_cli(tmp_path, body)
    assert summary["status"] == status, err
    assert summary["blackboard"]["n"] == n
    assert code == (0 if status == "SUCCESS" else 1)


def test_an_endless_loop_alone_runs_until_max_seconds(tmp_path) -> None:
    code, summary, err = run_cli(tmp_path, f'<Sequence><Script code="n := 0"/>{ENDLESS}</Sequence>', "--max-seconds", "1")
    assert code == 1 and summary["status"] == "FAILURE"
    assert summary["ticks"] == 100 and summary["blackboard"]["n"] == 100  # one cycle in each tick
    assert "stopped after --max-seconds 1 s" in err


def test_a_root_whose_children_were_all_skipped_ends_skipped_with_exit_0(registry, tmp_path, capsys) -> None:
    lib = tmp_path / "lib"
    lib.mkdir()
    path = tree_file(tmp_path, '<Sequence><AlwaysFailure _skipIf="true"/><Forever _skipIf="true"/></Sequence>')
    code = main(["run", str(path), "--json", "--objectives-dir", str(lib)], registry=registry)
    out, err = capsys.readouterr()
    assert code == 0
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["status"] == "SKIPPED" and summary["ticks"] == 1 and summary["failing_node"] is None
    assert "SKIPPED after 0.01 s: every child of the root was skipped" in err


SCRIPT_ERRORS = [
    ('<Script name="bump" code="count = 1"/>', "Script 'bump': script 'count = 1': blackboard entry 'count' does not exist; use ':=' to create it at column 1"),
    ('<Sequence><Script code="n := 1"/><Script name="retype" code="n = \'text\'"/></Sequence>',
     "Script 'retype': script \"n = 'text'\": entry 'n' holds a number; cannot store the string 'text' in it at column 3"),
    ('<Sequence><Script code="n := 1"/><SetBlackboard name="put" output_key="n" value="seven"/></Sequence>',
     "SetBlackboard 'put': value 'seven': entry 'n' holds a number; cannot store the string 'seven' in it"),
]


@pytest.mark.parametrize("failing, message", SCRIPT_ERRORS, ids=["undeclared", "retype", "set_blackboard"])
def test_a_script_error_stops_the_run_halting_what_runs(registry, tmp_path, failing, message) -> None:
    # The failing node sits in a Fallback whose second branch must not run, beside a RUNNING node
    # that must be halted (robot stopped, goals cancelled).
    body = (
        '<Parallel success_count="-1"><Forever name="motion"/>'
        f'<Sequence><Wait seconds="0.05"/><Fallback>{failing}<Script code="fallback := 1"/></Fallback></Sequence>'
        "</Parallel>"
    )
    path = tree_file(tmp_path, body)
    lib = tmp_path / "lib"
    lib.mkdir()
    options = RunOptions()
    context = make_context(options)
    loaded = load_tree(path, registry, context, objectives_dir=lib)
    result = run_tree(loaded, context, options)  # an error of the Objective: the run ends as ERROR
    assert (result.status, result.reason, result.exit_code) == ("ERROR", f"{path}:3: {message}", 2)
    motion = next(n.node for n in loaded.nodes if isinstance(n.node, Forever))
    assert motion.terminated == [Status.INVALID] and motion.status is Status.INVALID
    assert not loaded.blackboard.has("fallback")
    assert context.clock.now() == pytest.approx(0.06)  # the Wait's tick at 0.05 s, then the error


def test_a_script_error_exits_2_with_error_in_json(tmp_path) -> None:
    code, summary, err = run_cli(
        tmp_path, '<Fallback><Script name="bump" code="count = 1"/><AlwaysSuccess/></Fallback>'
    )
    assert code == 2 and summary["status"] == "ERROR"
    assert "t.xml:3: Script 'bump': script 'count = 1': blackboard entry 'count' does not exist" in summary["reason"]
    assert "Traceback" not in err and "error: " in err

