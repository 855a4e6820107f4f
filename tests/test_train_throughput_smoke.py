"""Smoke test of benchmarks/train_throughput.py with a tiny network and a few iterations."""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = str(Path(__file__).resolve().parents[1])  # `benchmarks` is not installed; plain `pytest`
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def test_train_throughput_smoke(tmp_path: Path) -> None:
    from benchmarks import train_throughput

    out = tmp_path / "train_throughput.json"
    argv = ["--batch-sizes", "8", "--num-envs", "4", "--iterations", "5"]
    argv += ["--hidden-sizes", "16", "--buffer-size", "400", "--out", str(out)]
    result = train_throughput.main(argv)
    data = json.loads(out.read_text())
    assert data == json.loads(json.dumps(result))
    machine = data["machine"]
    for field in ("platform", "cpu_count", "jax_version", "backend", "date"):
        assert machine[field], field
    assert data["config"]["hidden_sizes"] == [16] and data["config"]["env"] == "GridMaze-v0"
    assert data["config"]["learning_starts"] == 4  # num_envs * n_step: every iteration updates
    (row,) = data["results"]
    assert (row["batch_size"], row["num_envs"], row["iterations"]) == (8, 4, 5)
    assert row["buffer_rows"] == 100 and row["replay_ratio"] == 8 / 4
    for part in ("bare", "loop", "no_update_loop"):
        assert row[part]["compile_s"] > 0 and len(row[part]["run_s"]) == 3, part
        assert all(t > 0 for t in row[part]["run_s"]) and len(row[part]["cpu_s"]) == 3, part
    assert row["bare"]["updates"] == 5 and row["bare"]["updates_per_s"] > 0
    loop = row["loop"]
    assert loop["updates_per_s"] == loop["iterations_per_s"] > 0
    assert loop["env_steps_per_s"] == 4 * loop["iterations_per_s"]
    assert row["no_update_loop"]["iterations_per_s"] > 0
    assert row["ratio"] > 0 and row["ratio_best_runs"] > 0 and 0 < row["predicted_ratio"] < 1
    assert row["meets_goal"] == (row["ratio"] >= train_throughput.GOAL_RATIO)
    assert out.with_suffix(".md").read_text().startswith("| batch |")


def test_parse_args_rejects_bad_sizes() -> None:
    import pytest

    from benchmarks import train_throughput

    for bad in (["--iterations", "0"], ["--hidden-sizes", ""], ["--buffer-size", "64"]):
        with pytest.raises(SystemExit):
            train_throughput.parse_args(bad)
