"""`objective eval --executor ray` on a real local Ray instance (2 CPUs, loopback, no dashboard).

Skipped when Ray is not installed (`make ray`). The episodes are the kinematic stacking cut
short (--max-seconds) and the fault plug-in of test_eval.py, so the module stays short.
"""
from __future__ import annotations

import json
import os

import pytest

os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # node address 127.0.0.1 (see evaluation.ray_executor)
ray = pytest.importorskip("ray", reason="Ray is an optional extra: make ray")

from evaluation.config import RecordMode, WorkerSpec  # noqa: E402
from evaluation.episode import EpisodeRecord  # noqa: E402
from evaluation.policies import parse_policy  # noqa: E402
from evaluation.worker import EpisodeWorker  # noqa: E402
from runtime.app.cli import main  # noqa: E402

from .test_eval import PLUGIN, STACK, episodes, faults_objective  # noqa: E402

pytestmark = pytest.mark.timeout(420)


@pytest.fixture(scope="module")
def local_ray():
    """A real Ray instance for this module; its workers find the fault plug-in on PYTHONPATH."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(PLUGIN), os.environ.get("PYTHONPATH")])))
        patch.syspath_prepend(str(PLUGIN))
        ray.init(num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1", log_to_driver=False,
                 object_store_memory=128 * 1024 * 1024)
        try:
            assert ray.util.get_node_ip_address() == "127.0.0.1"
            yield
        finally:
            ray.shutdown()


def test_ray_episodes_equal_local_ones_and_recordings_come_back(local_ray, tmp_path, capsys):
    out = tmp_path / "eval"
    code = main(["eval", str(STACK), "--executor", "ray", "--workers", "2", "--episodes", "2", "--world", "kinematic",
                 "--max-seconds", "6", "--record", "failures", "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    summary = json.loads(captured.out.strip().splitlines()[-1])
    assert summary["executor"] == "ray" and summary["failures"] == 2
    by_seed = {line["seed"]: EpisodeRecord.from_json(line) for line in episodes(out)}
    assert sorted(by_seed) == [0, 1]
    assert {r.worker.rsplit(".", 1)[0] for r in by_seed.values()} <= {"ray-worker-0", "ray-worker-1"}
    # Not recorded here, in this process: neither the recording nor the process changes an episode.
    spec = WorkerSpec(objective=STACK, world="kinematic", policy=parse_policy("oracle"), max_seconds=6.0,
                      record=RecordMode.NONE)
    local = EpisodeWorker(spec, "local")
    local.warm_up()
    try:
        for seed, remote in by_seed.items():
            mine = local.run(seed)
            assert remote.seeded_view() == mine.seeded_view()
    finally:
        local.close()
    for seed in (0, 1):  # a failed episode's recording, made on the Ray worker, unpacked here
        assert (out / by_seed[seed].recording / "report.html").is_file()
        assert (out / by_seed[seed].recording / "run.mcap").stat().st_size > 0
    assert "id='seed-1'" in (out / "report.html").read_text()


def test_ray_lost_and_hung_workers_are_replaced_and_no_episode_counts_twice(local_ray, tmp_path, capsys):
    objective = faults_objective(tmp_path, crash=1, hang=2)
    out = tmp_path / "eval"
    code = main(["eval", str(objective), "--executor", "ray", "--workers", "2", "--episodes", "5",
                 "--episode-timeout", "10", "--record", "none", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1, err
    lines = episodes(out)
    assert sorted(line["seed"] for line in lines) == [0, 1, 2, 3, 4]
    by_seed = {line["seed"]: line for line in lines}
    assert [by_seed[s]["status"] for s in range(5)] == ["SUCCESS", "ERROR", "ERROR", "SUCCESS", "SUCCESS"]
    assert "its Ray worker ray-worker-" in by_seed[1]["reason"] and by_seed[1]["attempts"] == 2
    assert by_seed[1]["reason"].endswith("2 attempts, each lost its worker")
    assert by_seed[2]["reason"].startswith("no result within 10 s of wall time (--episode-timeout): the episode hung")
    assert "5 episodes: 3 successes (60.0 %" in err


def test_ray_refuses_what_it_cannot_run(tmp_path, capsys):
    code = main(["eval", str(STACK), "--episodes", "1", "--ray-address", "127.0.0.1:1", "--out", str(tmp_path / "x")])
    assert code == 2 and "--ray-address needs --executor ray" in capsys.readouterr().err
