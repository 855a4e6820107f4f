"""GridMaze-Random-v0's levers, measured through the command lines a user runs.

    python -m benchmarks.grid_random_sweep [--rows 0,3] [--seeds 0,1,2] [--episodes 10240]
    python -m benchmarks.grid_random_sweep --table-only   # rewrite the markdown from the JSONL

Each row (``ROWS``) is ``python -m jaxnav.train --env GridMaze-Random-v0`` with the row's flags
(none for the default row: the command as a user types it), one training per seed, one after
another. Every run is then evaluated greedily with ``python -m jaxnav.evaluate`` on
``--episodes`` episodes (test seed 0, layouts round-robin) of held-out layouts: a bank of 1024
layouts of the default generator (15x15, obstacle density 0.2, 16 goals each) from
``layout_seed`` ``HELD_OUT_LAYOUT_SEED``, which shares no layout with the training banks of
``layout_seed`` 0, up to 16,384 layouts (tests/test_grid_maze.py). Training-bank success is
the training command's own evaluation (1000 episodes). Train seconds are what the training
command prints (compile excluded), on whatever machine runs this; the markdown says which, with
the 1-minute load average before each run (other processes slow a run down).

One JSON line per (row, seed) is appended to ``--out`` (``.jsonl``); the markdown table beside
it (``.md``) summarizes the latest line of each (row, seed).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import machine_info
from jaxnav.envs.grid_maze import HELD_OUT_LAYOUT_SEED
from jaxnav.run_dir import config_from_json

ENV = "GridMaze-Random-v0"
# the held-out bank: the default generator's settings, spelled out so that a row training on
# another bank size or density is still tested on the same layouts
HELD_OUT = {
    "layout_seed": HELD_OUT_LAYOUT_SEED,
    "num_layouts": 1024,
    "goals_per_layout": 16,
    "obstacle_density": 0.2,
}
# GridMaze-Random-v0 as it was before this sweep: no waypoint, trained by the paper's DQN
# (``--algo dqn``: TrainConfig's defaults, 240k steps)
NO_WAYPOINT = {"waypoint_cells": 0}
DQN: dict[str, Any] = {"algo": "dqn"}
# the PQN preset GridMaze-Random-v0 had before: the paper's MLP, TrainConfig's logging interval
OLD_PQN: dict[str, Any] = {"algo": "pqn", "hidden_sizes": "512,256,128,64", "log_interval": 16_000}
# (label, env overrides, training flags); a row without either is the default command as a
# user types it: PQN (GRID_RANDOM_PQN in jaxnav/presets.py) with the waypoint 3 cells ahead
ROWS: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("before: DQN 240k, no waypoint", NO_WAYPOINT, DQN),
    ("before, 480k steps", NO_WAYPOINT, {**DQN, "total_timesteps": 480_000}),
    ("before, bank of 16384 layouts", {**NO_WAYPOINT, "num_layouts": 16384}, DQN),
    ("before, 7x7 window", {**NO_WAYPOINT, "sensor_radius": 3}, DQN),
    ("before, PQN 240k", NO_WAYPOINT, {**OLD_PQN, "total_timesteps": 240_000}),
    ("DQN 240k, waypoint 1 cell ahead", {"waypoint_cells": 1}, DQN),
    ("DQN 240k, waypoint 2 cells ahead", {"waypoint_cells": 2}, DQN),
    ("DQN 240k, waypoint 3 cells ahead", {"waypoint_cells": 3}, DQN),
    ("DQN 240k, waypoint 4 cells ahead", {"waypoint_cells": 4}, DQN),
    ("DQN 240k, waypoint 3, gamma 0.95", {"waypoint_cells": 3}, {**DQN, "gamma": 0.95}),
    ("DQN 400k, waypoint 3", {"waypoint_cells": 3}, {**DQN, "total_timesteps": 400_000}),
    (
        "DQN 240k, waypoint 3, step reward -0.1, gamma 0.95",
        {"waypoint_cells": 3, "step_reward": -0.1},
        {**DQN, "gamma": 0.95},
    ),
    ("PQN 240k, waypoint 3", {"waypoint_cells": 3}, {**OLD_PQN, "total_timesteps": 240_000}),
    ("PQN 960k, waypoint 3", {"waypoint_cells": 3}, {**OLD_PQN, "total_timesteps": 960_000}),
    (
        "PQN 960k, waypoint 3, gamma 0.95",
        {"waypoint_cells": 3},
        {**OLD_PQN, "total_timesteps": 960_000, "gamma": 0.95},
    ),
    ("default, 960k steps", {}, {"total_timesteps": 960_000}),
    ("default: PQN 1.92M, 256-128-64 MLP, waypoint 3", {}, {}),
    ("default, waypoint 2", {"waypoint_cells": 2}, {}),
    ("default, waypoint 4", {"waypoint_cells": 4}, {}),
    ("default, no waypoint", NO_WAYPOINT, {}),
    ("default, bank of 16384 layouts", {"num_layouts": 16384}, {}),
    ("default, 2.88M steps", {}, {"total_timesteps": 2_880_000}),
]


def flags(env_kwargs: dict[str, Any], train: dict[str, Any]) -> list[str]:
    """Command-line flags of a row."""
    out: list[str] = []
    for k, v in env_kwargs.items():
        out += ["--env-arg", f"{k}={json.dumps(v)}"]
    for k, v in train.items():
        out += ["--" + k.replace("_", "-"), str(v)]
    return out


def run(cmd: list[str]) -> None:
    print("$", " ".join(cmd), flush=True)
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"{cmd[2]} failed ({done.returncode}):\n{done.stdout}\n{done.stderr}")


def measure(label: str, argv: list[str], seed: int, episodes: int, tmp: Path) -> dict[str, Any]:
    """Train one seed with the CLI, evaluate it on the held-out bank; one result line."""
    out = tmp / f"run-{len(list(tmp.iterdir()))}"
    py = sys.executable
    load = os.getloadavg()[0]
    run([py, "-m", "jaxnav.train", "--env", ENV, *argv, "--seed", str(seed), "--out", str(out),
         "--quiet"])  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    config = json.loads((out / "config.json").read_text())
    held = out / "held_out.json"
    run([py, "-m", "jaxnav.evaluate", str(out), *flags(HELD_OUT, {}),
         "--episodes", str(episodes), "--out", str(held)])  # fmt: skip
    h = json.loads(held.read_text())
    return {
        "label": label,
        "seed": seed,
        "flags": argv,
        "config": config["config"],
        "train_s": summary["train_s"],
        "compile_s": summary["compile_s"],
        "train_bank": summary["trained"],
        "held_out": {k: h[k] for k in ("episodes", "success_rate", "collision_rate",
                                       "timeout_rate", "worst10_success", "mean_path_ratio")},
        "loadavg_1m_before": load,
        "machine": machine_info(),
        "time": time.strftime("%Y-%m-%d %H:%M:%S"),
    }  # fmt: skip


def env_steps(line: dict[str, Any]) -> int:
    """Env steps the run trained for: ``total_timesteps`` rounded up to whole logging
    intervals of whole iterations."""
    config = config_from_json(line["config"])
    return config.iterations * config.steps_per_iteration


def _stat(rows: list[dict[str, Any]], get: Any) -> str:
    """Mean over ``rows`` of ``get(row)`` (None left out), the minimum in brackets."""
    vals = [v for v in (get(r) for r in rows) if v is not None]
    if not vals:
        return "n/a"
    return f"{np.mean(vals):.3f}" + (f" ({min(vals):.3f})" if len(vals) > 1 else "")


def markdown(lines: list[dict[str, Any]]) -> str:
    """Per row (in ``ROWS`` order, then any other label): means over seeds (min in brackets)."""
    latest: dict[tuple[str, int], dict[str, Any]] = {}
    for r in lines:
        latest[(r["label"], r["seed"])] = r
    labels = [r[0] for r in ROWS] + sorted({k[0] for k in latest} - {r[0] for r in ROWS})
    flag_of = {r[0]: " ".join(flags(r[1], r[2])) or "(none: the default command)" for r in ROWS}
    out = [
        f"# {ENV} levers (benchmarks/grid_random_sweep.py)\n",
        "Held-out: greedy episodes on 1024 layouts of `layout_seed` "
        f"{HELD_OUT_LAYOUT_SEED} (none of them in a training bank), round-robin; training bank: "
        "the training command's 1000 episodes. Means over seeds, the lowest seed in brackets. "
        "Env steps: what the run trained for (total_timesteps rounded up to whole logging "
        "intervals). Train s: the training command's own figure (compile excluded); load avg: "
        "the machine's 1-minute load average before the run.\n",
        "| row | flags | seeds | env steps | held-out success | held-out worst-10% | "
        "held-out episodes | training-bank success | train s | load avg |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    machines = set()
    for label in labels:
        rows = [latest[k] for k in sorted(latest) if k[0] == label]
        if not rows:
            continue
        machines |= {f"{r['machine']['cpu_count']}-core {r['machine']['backend']}" for r in rows}

        out.append(
            f"| {label} | `{flag_of.get(label, ' '.join(rows[0]['flags']))}` | "
            f"{','.join(str(r['seed']) for r in rows)} | {env_steps(rows[0]):,} | "
            f"{_stat(rows, lambda r: r['held_out']['success_rate'])} | "
            f"{_stat(rows, lambda r: r['held_out']['worst10_success'])} | "
            f"{int(rows[0]['held_out']['episodes'])} | "
            f"{_stat(rows, lambda r: r['train_bank']['success_rate'])} | "
            f"{np.mean([r['train_s'] for r in rows]):.1f} | "
            f"{np.mean([r['loadavg_1m_before'] for r in rows]):.1f} |"
        )
    out.append(f"\nMachines: {', '.join(sorted(machines))}.")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", help="comma-separated row indices (default: all)")
    ap.add_argument("--seeds", default="0", help="comma-separated training seeds")
    ap.add_argument("--episodes", type=int, default=10240, help="held-out episodes per run")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/grid_random_sweep.jsonl"))
    ap.add_argument("--table-only", action="store_true", help="rewrite the markdown only")
    args = ap.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not args.table_only:
        picked = range(len(ROWS)) if args.rows is None else map(int, args.rows.split(","))
        seeds = [int(s) for s in args.seeds.split(",")]
        with tempfile.TemporaryDirectory() as tmp:
            for i in picked:
                label, env_kwargs, train = ROWS[i]
                for seed in seeds:
                    line = measure(label, flags(env_kwargs, train), seed, args.episodes, Path(tmp))
                    with args.out.open("a") as f:
                        f.write(json.dumps(line) + "\n")
                    print(
                        f"{label} seed {seed}: held-out {line['held_out']['success_rate']:.3f}, "
                        f"training bank {line['train_bank']['success_rate']:.3f}, "
                        f"train {line['train_s']:.1f}s",
                        flush=True,
                    )
    lines = [json.loads(x) for x in args.out.read_text().splitlines() if x.strip()]
    md = markdown(lines)
    args.out.with_suffix(".md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
