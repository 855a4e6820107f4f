"""Sim-to-real noise: a policy trained without noise and one trained with it, each tested on
fresh episodes without and with the noise.

    python -m benchmarks.noise_table [--runs runs/noise_table] [--seeds 2] [--episodes 1000]

Both train the same way (PQN, the robot PQN preset, ``--total-timesteps`` env steps on
RobotSimple-v0 with the kinematic backend and the generalist's sensors: 32 beams all around
read to 3.5 m, no absolute coordinates, a waypoint 2 cells ahead), one of them with ``NOISE``
(``jaxnav.envs.robot.env``: laser range noise and dropout, actuation noise, control-period
jitter, the robot's radius per episode). Each trained seed is tested greedily on the same
fresh episodes (seed 10,000) of both envs. Runs that exist in ``--runs`` are reused. Writes
``benchmarks/results/noise_table.{json,md}``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from jaxnav import run_dir
from jaxnav.envs.robot.env import GENERALIST_SENSORS
from jaxnav.evaluate import evaluate_seeds
from jaxnav.train import Trainer
from jaxnav.train.__main__ import main as train_main

ENV = "RobotSimple-v0"
BASE: dict[str, Any] = {"backend": "kinematic", **GENERALIST_SENSORS}
# a cheap lidar's and a small robot's errors: 3 cm + 2% range noise, 5% of beams lost, 10%
# speed and turn-rate errors and control-period jitter, a radius of 0.12-0.18 m per episode
NOISE: dict[str, Any] = {
    "laser_noise": 0.03,
    "laser_noise_rel": 0.02,
    "laser_dropout": 0.05,
    "speed_noise": 0.1,
    "turn_noise": 0.1,
    "dt_jitter": 0.1,
    "radius_range": [0.12, 0.18],
}
RESULTS = Path(__file__).parent / "results"
COLUMNS = ("success_rate", "collision_rate", "timeout_rate", "mean_steps")


def env_args(kwargs: dict[str, Any]) -> list[str]:
    return [a for k, v in kwargs.items() for a in ("--env-arg", f"{k}={json.dumps(v)}")]


def train(out: Path, kwargs: dict[str, Any], seeds: int, steps: int) -> float:
    """Train the run ``out`` unless it exists; its training seconds."""
    if not (out / "summary.json").is_file():
        argv = [
            "--env", ENV, "--algo", "pqn", "--num-seeds", str(seeds),
            "--total-timesteps", str(steps), "--eps-decay-steps", str(steps * 2 // 5),
            "--eval-episodes", "100", "--quiet", "--out", str(out), *env_args(kwargs),
        ]  # fmt: skip
        if train_main(argv) != 0:
            raise SystemExit(f"training {out} failed")
    return json.loads((out / "summary.json").read_text())["train_s"]


def test(run: Path, kwargs: dict[str, Any], episodes: int) -> list[dict[str, Any]]:
    """Each seed of ``run`` on ``episodes`` fresh episodes of ``ENV`` with exactly ``kwargs``."""
    config = run_dir.load_config(run)
    params = run_dir.load_trained_params(run, Trainer(config))
    trainer = Trainer(dataclasses.replace(config, env_kwargs=kwargs))
    return evaluate_seeds(trainer, params, episodes, seed=10_000)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=Path, default=Path("runs/noise_table"))
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--steps", type=int, default=1_000_000)
    p.add_argument("--episodes", type=int, default=1000)
    args = p.parse_args(argv)
    args.runs.mkdir(parents=True, exist_ok=True)
    envs = {"without noise": BASE, "with noise": {**BASE, **NOISE}}
    t0 = time.perf_counter()
    rows, train_s = [], {}
    for trained, kwargs in envs.items():
        run = args.runs / ("clean" if trained == "without noise" else "noisy")
        train_s[trained] = train(run, kwargs, args.seeds, args.steps)
        for tested, test_kwargs in envs.items():
            per_seed = test(run, test_kwargs, args.episodes)
            mean = {k: float(np.mean([r[k] for r in per_seed])) for k in COLUMNS}
            rows.append(
                {"trained": trained, "tested": tested, **mean,
                 "success_per_seed": [r["success_rate"] for r in per_seed]}
            )  # fmt: skip
            print(rows[-1], flush=True)
    result = {
        "env": ENV,
        "env_kwargs": BASE,
        "noise": NOISE,
        "seeds": args.seeds,
        "total_timesteps": args.steps,
        "episodes": args.episodes,
        "train_s": train_s,
        "wall_s": time.perf_counter() - t0,
        "rows": rows,
    }
    (RESULTS / "noise_table.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [
        f"# Trained without and with noise, tested without and with it ({ENV})",
        "",
        f"`python -m benchmarks.noise_table --seeds {args.seeds} --steps {args.steps} "
        f"--episodes {args.episodes}` on this 2-core CPU. PQN, {args.steps:,} env steps "
        f"(rounded up to logging intervals) per seed, {args.seeds} seeds each; sensors "
        f"{json.dumps(BASE)}; noise {json.dumps(NOISE)}. Means over seeds, greedy policy on "
        f"the same {args.episodes} fresh episodes (seed 10,000) per seed.",
        "",
        "| trained | tested | success | collision | timeout | mean steps | success per seed |",
        "|---|---|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        seeds = ", ".join(f"{s:.3f}" for s in r["success_per_seed"])
        lines.append(
            f"| {r['trained']} | {r['tested']} | {r['success_rate']:.3f} | "
            f"{r['collision_rate']:.3f} | {r['timeout_rate']:.3f} | {r['mean_steps']:.1f} | "
            f"{seeds} |"
        )
    lines += ["", f"Training: {', '.join(f'{k} {v:.0f} s' for k, v in train_s.items())}."]
    (RESULTS / "noise_table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
