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
