"""Smoke test of benchmarks/env_throughput.py at tiny sizes (our envs only)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = str(Path(__file__).resolve().parents[1])  # `benchmarks` is not installed; plain `pytest`
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def test_env_throughput_smoke(tmp_path: Path) -> None:
    from benchmarks import env_throughput

    out = tmp_path / "env_throughput.json"
    envs = ",".join(env_throughput.OUR_ENVS)
    result = env_throughput.main(
        ["--num-envs", "1,4", "--steps", "10", "--rounds", "2", "--envs", envs, "--out", str(out)]
    )
    data = json.loads(out.read_text())
    assert data == json.loads(json.dumps(result))
    machine = data["machine"]
    for field in ("platform", "cpu_count", "jax_version", "backend", "date"):
        assert machine[field], field
    rows = data["results"]
    assert {(r["env"], r["num_envs"]) for r in rows} == {
        (e, n) for e in env_throughput.OUR_ENVS for n in (1, 4)
    }
    for r in rows:
        assert r["steps"] == 10
        assert r["compile_s"] > 0 and r["steps_per_s"] > 0 and len(r["run_s"]) == 2
        assert r["baseline"] == "GridMaze-v0" and r["ratio"] > 0
    assert set(data["autoreset_cost"]) == {"1", "4"}
    assert out.with_suffix(".md").read_text().startswith("| env |")


def test_grid_sweep_smoke(tmp_path: Path) -> None:
    from benchmarks import grid_sweep

    out = tmp_path / "sweep.json"
    tiny = {
        "env_kwargs": {"size": 5},
        "hidden_sizes": [16],
        "total_timesteps": 2000,
        "learning_starts": 500,
        "log_interval": 500,
        "buffer_size": 1000,
        "batch_size": 16,
        "num_envs": 4,  # 500 / 4 iterations per log: exactly 4 logs
    }
    rows = grid_sweep.main(
        [
            "--seeds",
            "2",
            "--eval-episodes",
            "20",
            "--out",
            str(out),
            "--variant",
            "tiny",
            json.dumps(tiny),
        ]
    )
    data = json.loads(out.read_text())
    assert [r["name"] for r in data["rows"]] == ["tiny"] == [r["name"] for r in rows]
    row = data["rows"][0]
    assert len(row["per_seed"]) == 2 and 0.0 <= row["success_min"] <= row["success_mean"] <= 1.0
    assert len(row["train_success_curve"]) == 4
    assert data["meta"]["machine"]["jax_version"]
    assert out.with_suffix(".md").read_text().count("\n") == 3
