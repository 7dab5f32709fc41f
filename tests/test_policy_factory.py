"""Your own policy in one file (``policy.factory``): ``objective serve --backend FILE.py:NAME`` and
``objective run --policy FILE.py:NAME | MODULE:NAME | http(s)://...``, with every mistake named."""
from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from policy.factory import FactoryError, build_backend, is_factory_spec, load_factory
from policy.replay import RecordedChunk, ReplayBackend, write_replay
from policy.server import BackendOptions, make_backend
from policy.specs import PolicyKind, PolicySpecError, parse_policy
from runtime.app.cli import main
from sim.robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, load_waypoints

HOLD = '''
from pathlib import Path

from policy.replay import ReplayBackend


def make(options):
    """Replays hold.jsonl beside this file."""
    return ReplayBackend(Path(__file__).with_name("hold.jsonl"))
'''


@pytest.fixture
def policy_dir(tmp_path):
    home = load_waypoints()["Home"]
    row = [home[j] for j in ARM_JOINTS] + [0.0]
    write_replay(tmp_path / "hold.jsonl",
                 [RecordedChunk(list(ARM_JOINTS) + [GRIPPER_DRIVER_JOINT], np.tile(row, (50, 1)), 0.1) for _ in range(4)])
    (tmp_path / "my_policy.py").write_text(HOLD)
    return tmp_path


def write(tmp_path, text: str, name: str = "my_policy.py") -> str:
    (tmp_path / name).write_text(textwrap.dedent(text))
    return str(tmp_path / name)


def test_a_file_factory_builds_the_backend(policy_dir):
    backend = build_backend(f"{policy_dir}/my_policy.py:make", BackendOptions())
    assert isinstance(backend, ReplayBackend) and backend.name == "replay"


def test_a_module_factory_builds_the_backend(policy_dir, monkeypatch):
    monkeypatch.syspath_prepend(str(policy_dir))
    assert isinstance(make_backend("my_policy:make", BackendOptions()), ReplayBackend)


@pytest.mark.parametrize("text, factory", [
    ("my_policy.py:make", True), ("pkg.module:make_backend", True), ("./policies/p.py:f", True),
    ("replay", False), ("my_policy.py", False), ("my_policy.py:", False), ("a b:make", False), ("x:1abc", False),
])
def test_what_a_factory_spec_looks_like(text, factory):
    assert is_factory_spec(text) is factory


@pytest.mark.parametrize("source, message", [
    ("def make(options):\n    raise RuntimeError('no GPU here')\n",
     "policy factory {path}:make raised RuntimeError: no GPU here"),
    ("def make(options):\n    return 42\n",
     "policy factory {path}:make returned int, not a policy backend (it lacks load(), warmup(), infer(); "
     "a backend has name, load(), warmup(request) and infer(request))"),
    ("class B:\n    def load(self): ...\n    def warmup(self, r): ...\n    def infer(self, r): ...\n"
     "def make(options):\n    return B()\n",
     "policy factory {path}:make returned B, not a policy backend (it lacks a name (str); "
     "a backend has name, load(), warmup(request) and infer(request))"),
    ("def other(options):\n    pass\n",
     "policy factory {path}:make: {path} defines no 'make' (callables it defines: other)"),
    ("make = 3\n", "policy factory {path}:make: 'make' is a int, not a function"),
    ("import no_such_module_here\n",
     "policy factory {path}:make: importing {path} raised ModuleNotFoundError: No module named 'no_such_module_here'"),
    ("def make(options)\n    pass\n", "policy factory {path}:make: importing {path} raised SyntaxError: "),
])
def test_a_factory_that_gives_no_backend_is_named_with_its_file(tmp_path, source, message):
    path = write(tmp_path, source)
    with pytest.raises(FactoryError) as caught:
        build_backend(f"{path}:make", BackendOptions())
    assert str(caught.value).startswith(message.format(path=path))


def test_a_missing_file_or_module_is_named(tmp_path):
    with pytest.raises(FactoryError, match=r"policy factory nowhere\.py:make: no such file nowhere\.py$"):
        load_factory("nowhere.py:make")
    with pytest.raises(FactoryError, match=r"no module named 'no_such_pkg\.policies' \(a file is named FILE\.py:NAME\)"):
        load_factory("no_such_pkg.policies:make")


def test_policy_specs_are_parsed_in_one_place(policy_dir):
    spec = parse_policy(f"{policy_dir}/my_policy.py:make")
    assert spec.kind is PolicyKind.FACTORY and spec.path == policy_dir / "my_policy.py"
    assert parse_policy("my_pkg.policies:make").kind is PolicyKind.FACTORY
    assert parse_policy(f"replay:{policy_dir}/hold.jsonl").kind is PolicyKind.REPLAY
    assert parse_policy("http://127.0.0.1:8000").kind is PolicyKind.HTTP
    with pytest.raises(PolicySpecError, match=r"^policy 'gone\.py:make': no such file gone\.py$"):
        parse_policy("gone.py:make")
    with pytest.raises(PolicySpecError, match=r"^policy 'http://example\.com:8000': "):
        parse_policy("http://example.com:8000")  # plain http leaves loopback only


def run_json(capsys, *args: str) -> tuple[int, dict]:
    code = main(["run", *args, "--json"])
    return code, json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_run_policy_takes_a_factory_file(capsys, policy_dir):
    code, summary = run_json(capsys, "objectives/stack_cubes.xml", "--world", "kinematic",
                             "--policy", f"{policy_dir}/my_policy.py:make")
    assert code == 1 and summary["failing_node"] == "top cube on bottom cube"  # held still: nothing stacked
    assert summary["execute_policy"]["message"] == "the policy has no more actions: replay of 'hold.jsonl' finished after 4 chunks"


def test_run_policy_names_a_factory_that_raises(capsys, tmp_path):
    path = write(tmp_path, "def make(options):\n    raise RuntimeError('weights not found')\n")
    assert main(["run", "objectives/stack_cubes.xml", "--world", "kinematic", "--policy", f"{path}:make"]) == 2
    err = capsys.readouterr().err
    assert f"error: world 'kinematic': policy factory {path}:make raised RuntimeError: weights not found" in err
    assert "Traceback" not in err


def test_run_policy_takes_an_inference_server(capsys, policy_dir):
    """``--policy http://...`` in a headless run: the chunks come from ``objective serve``'s backend."""
    from policy.server import InferenceServer, ServerConfig

    server = InferenceServer(make_backend(f"{policy_dir}/my_policy.py:make", BackendOptions()),
                             ServerConfig(port=0, insecure_no_key=True))
    server.start()
    try:
        assert server.ready.wait(10)
        code, summary = run_json(capsys, "objectives/stack_cubes.xml", "--world", "kinematic", "--policy", server.url)
    finally:
        server.stop()
    assert code == 1 and summary["failing_node"] == "top cube on bottom cube"
    assert summary["execute_policy"]["chunks"] == 4


def test_a_factory_file_travels_to_a_ray_worker_as_its_file(policy_dir, tmp_path):
    """``objective eval --executor ray`` ships FILE.py of ``FILE.py:NAME`` and names the copy."""
    from evaluation.config import WorkerSpec
    from evaluation.policies import parse_policy as eval_policy
    from evaluation.ray_executor import pack_inputs, unpack_inputs

    spec = WorkerSpec(objective=Path("objectives/stack_cubes.xml").resolve(), world="kinematic",
                      policy=eval_policy(f"{policy_dir}/my_policy.py:make"))
    inputs = pack_inputs(spec)
    assert inputs["policy"] == {"my_policy.py": HOLD.encode()}
    local = unpack_inputs(spec, inputs, tmp_path / "node")
    assert local.policy.kind is PolicyKind.FACTORY
    assert local.policy.text == f"{tmp_path / 'node' / 'policy' / 'my_policy.py'}:make"
    assert (tmp_path / "node" / "policy" / "my_policy.py").read_text() == HOLD


EXITING = '''
import sys


class Exiting:
    name = "exiting"

    def load(self):
        {load}

    def warmup(self, request):
        pass

    def infer(self, request):
        {infer}


def make(options):
    {make}
    return Exiting()
'''


@pytest.mark.parametrize("raises, text", [("sys.exit(7)", "SystemExit: 7"), ("raise KeyboardInterrupt", "KeyboardInterrupt")])
def test_a_policy_that_exits_or_raises_keyboard_interrupt_is_a_policy_error(capsys, tmp_path, raises, text):
    """Neither ends the process (exit 7, nothing said) nor reads as Ctrl-C: the policy answered ERROR."""
    path = write(tmp_path, EXITING.format(load="pass", infer=raises, make="pass"))
    code, summary = run_json(capsys, "objectives/stack_cubes.xml", "--world", "kinematic", "--policy", f"{path}:make")
    assert code == 2  # a policy refusing its warmup is a setup error: no Retry repeats it
    assert summary["status"] == "ERROR" and summary["failing_node"] == "ExecutePolicy"
    assert summary["reason"].endswith(f"the policy answered ERROR for the warmup: policy backend 'exiting' failed: {text}")


@pytest.mark.parametrize("where", ["make", "load"])
def test_a_policy_that_exits_while_it_loads_is_an_error_naming_it(capsys, tmp_path, where):
    path = write(tmp_path, EXITING.format(**{"load": "pass", "infer": "pass", "make": "pass", where: "sys.exit(7)"}))
    code, summary = run_json(capsys, "objectives/stack_cubes.xml", "--world", "kinematic", "--policy", f"{path}:make")
    assert code == 2 and summary["status"] == "ERROR"
    said = {"make": f"policy factory {path}:make raised SystemExit: 7",
            "load": "policy backend 'exiting' failed to load: SystemExit: 7"}[where]
    assert summary["reason"] == f"world 'kinematic': {said}"


FORGING = '''
class Forging:
    name = "forging\\u202e"

    def load(self):
        pass

    def warmup(self, request):
        pass

    def infer(self, request):
        raise RuntimeError("\\x1b[2K\\r\\nSUCCESS after 1.00 s\\u202e" + "x" * 5_000_000)


def make(options):
    return Forging()
'''


def test_a_policy_s_error_text_is_escaped_and_cut_everywhere_it_is_printed(capsys, tmp_path):
    """ESC, CR-LF and a right-to-left override cannot forge a SUCCESS line, and a 5 MB message
    prints as 4,096 characters and how many were cut (the adapter's warning, the outcome line, --json)."""
    path = write(tmp_path, FORGING)
    assert main(["run", "objectives/stack_cubes.xml", "--world", "kinematic", "--policy", f"{path}:make", "--json"]) == 2
    out, err = capsys.readouterr()
    for text in (out, err):
        assert "\x1b" not in text and "\r" not in text and "\u202e" not in text
    assert len(err) < 20_000 and len(out) < 30_000
    said = "policy backend 'forging\\u202e' failed: RuntimeError: \\x1b[2K\\r\\nSUCCESS after 1.00 s\\u202exxx"
    assert f"[WARNING] policy.adapter: answered ERROR: {said}" in err
    assert f"error: objectives/stack_cubes.xml:12: ExecutePolicy: the policy answered ERROR for the warmup: {said}" in err
    assert [line for line in err.splitlines() if "SUCCESS" in line and not line.startswith(("[WARNING]", "error:"))] == []
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["reason"].endswith("x... (4996021 characters cut)")
    where = "objectives/stack_cubes.xml:12: ExecutePolicy: "  # an ERROR's reason names the node first
    assert summary["reason"].startswith(where)
    assert len(summary["reason"]) == len(where) + 4096 + len("... (4996021 characters cut)")
