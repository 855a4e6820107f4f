"""Smoke test of benchmarks/train_throughput.py: both algorithms, a tiny network, a few
iterations."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = str(Path(__file__).resolve().parents[1])  # `benchmarks` is not installed; plain `pytest`
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def test_train_throughput_smoke(tmp_path: Path) -> None:
    from benchmarks import train_throughput

    out = tmp_path / "train_throughput.json"
    argv = ["--algos", "dqn,pqn", "--num-envs", "4,8", "--iterations", "4"]
    argv += ["--hidden-sizes", "16", "--env-arg", "size=5", "--rollout-length", "2"]
    argv += ["--num-minibatches", "2", "--batch-size", "8", "--replay-ratio", "2"]
    argv += ["--out", str(out)]
    result = train_throughput.main(argv)
    data = json.loads(out.read_text())
    assert data == json.loads(json.dumps(result))
    for field in ("platform", "cpu_count", "jax_version", "backend", "date"):
        assert data["machine"][field], field
    assert data["command"].startswith("python -m benchmarks.train_throughput --algos dqn,pqn")
    assert (data["env"], data["env_kwargs"], data["rounds"]) == ("GridMaze-v0", {"size": 5}, 3)
    env_alone = {e["num_envs"]: e for e in data["env_alone"]}
    assert sorted(env_alone) == [4, 8]
    for e in env_alone.values():
        assert e["steps"] >= 4 * 2 and e["compile_s"] > 0 and e["env_steps_per_s"] > 0
        assert len(e["run_s"]) == len(e["cpu_s"]) == 3 and min(e["run_s"]) > 0
    rows = {(r["algo"], r["num_envs"]): r for r in data["results"]}
    assert sorted(rows) == [("dqn", 4), ("dqn", 8), ("pqn", 4), ("pqn", 8)]
    for (algo, n), r in rows.items():
        config = r["config"]
        assert (config["algo"], config["num_envs"], config["hidden_sizes"]) == (algo, n, [16])
        assert config["env_kwargs"] == {"size": 5}
        if algo == "pqn":  # PQN's knobs, the preset's epochs; minibatch n * 2 / 2
            assert (config["rollout_length"], config["num_minibatches"]) == (2, 2)
            assert r["minibatch_size"] == n and r["steps_per_iteration"] == 2 * n
            assert r["updates_per_iteration"] == config["num_epochs"] * 2
            assert config["layer_norm"]  # the PQN preset
        else:  # DQN's knobs only; learning from the first iteration
            assert (config["rollout_length"], config["batch_size"]) == (1, 8)
            assert config["replay_ratio"] == 2.0  # 2 * n / 8 gradient steps of 8: 1 and 2
            assert r["minibatch_size"] == 8 and r["updates_per_iteration"] == n // 4
            assert config["learning_starts"] == n * config["n_step"]
        assert r["iterations"] == 4 and r["prep_s"] > 0
        train, update = r["train"], r["update"]
        for part in (train, update):
            assert part["compile_s"] > 0 and len(part["run_s"]) == len(part["cpu_s"]) == 3
            assert min(part["run_s"]) > 0
        assert train["env_steps"] == 4 * r["steps_per_iteration"]
        assert update["updates"] == 4 * r["updates_per_iteration"]
        assert train["env_steps_per_s"] == pytest.approx(
            train["iterations_per_s"] * r["steps_per_iteration"]
        )
        assert update["env_steps_per_s"] == pytest.approx(
            update["updates_per_s"] * r["steps_per_iteration"] / r["updates_per_iteration"]
        )
        assert r["env_alone_steps_per_s"] == env_alone[n]["env_steps_per_s"]
        for bound, key in (
            (r["env_alone_steps_per_s"], "fraction_of_env_alone"),
            (update["env_steps_per_s"], "fraction_of_update"),
            (r["serial_bound_steps_per_s"], "fraction_of_serial"),
        ):
            assert r[key] == pytest.approx(train["env_steps_per_s"] / bound), key
        # whether the bounds bound training is a measurement (benchmarks/results), not a
        # behaviour: on a loaded 2-core machine a 4-iteration bare update can time 2x slow
        assert r["fraction_of_env_alone"] > 0 and r["fraction_of_update"] > 0
    md = out.with_suffix(".md").read_text()
    assert md.startswith("GridMaze-v0 size=5, network 16 float32") and "| pqn | 8 | 8 |" in md
    assert out.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "bad",
    [
        ["--iterations", "0"],
        ["--hidden-sizes", ""],
        ["--num-envs", "4,x"],
        ["--algos", "dqn,sac"],
        ["--env", "NoSuchEnv-v0"],
        ["--env-arg", "size=-3"],
        ["--num-envs", "3", "--algos", "pqn", "--num-minibatches", "5", "--rollout-length", "1"],
        ["--compute-dtype", "float8"],
    ],
)
def test_parse_args_rejects_bad_values(bad: list[str], capsys: pytest.CaptureFixture) -> None:
    from benchmarks import train_throughput

    with pytest.raises(SystemExit) as e:
        train_throughput.parse_args(bad)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("python -m benchmarks.train_throughput: error")


def test_cli_bad_value_one_line_exit_2(tmp_path: Path) -> None:
    out = tmp_path / "never.json"
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks.train_throughput", "--num-envs", "0", "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "--num-envs '0'" in done.stderr and not out.exists()
