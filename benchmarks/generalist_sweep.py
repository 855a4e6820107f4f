"""The generalist's levers, measured: PQN on ``RobotNav-v0`` with one setting changed per row,
each trained once and tested greedily on held-out mazes, the paper's mazes and the maze files.

    python -m benchmarks.generalist_sweep [--rows 0,3] [--episodes 1000] \
        [--out benchmarks/results/generalist_sweep.jsonl]

Every row is ``TrainConfig.for_env("RobotNav-v0", algo="pqn")`` with the row's env and training
overrides, seed 0, ``eval_episodes`` 0. After training, ``--episodes`` greedy episodes (test
key 1234, mazes round-robin) on: the training bank; 1,000 held-out mazes (``maze_seed``
1,000,003); RobotSimple-v0, RobotComplex-v0 and every file of examples/mazes with the run's
settings (``experiments.default_families``). One JSON line per row (appended to ``--out``) and a
markdown table beside it. Rows run one after another in one process; each is a full training.

Rows 0-25 were measured while the waypoint's lookahead was counted in cells of each maze, so
their maze-file cells looked 2 cells ahead there (2 m on 1 m cells, 1.5 m on warehouse.txt's
0.75 m), where this script now looks ``waypoint_distance`` metres ahead (1 m: 1 cell); their
training, held-out and RobotComplex-v0 cells (0.5 m cells) are the same either way.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

import jaxnav
from benchmarks.common import machine_info
from jaxnav.config import TrainConfig
from jaxnav.envs.robot.env import LASER_SCALE
from jaxnav.evaluate import run_episodes
from jaxnav.experiments import Family, default_families
from jaxnav.train import Trainer, jit_training

# RobotNav-v0 before the levers below: the paper's speed, turn rate and reward terms, a 14 m
# lidar, no waypoint
BEFORE = {
    "laser_range": LASER_SCALE,
    "turn_speed": 5.0,
    "max_steps": 400,
    "collision_reward": -5.0,
    "step_reward_start": -0.5,
    "step_reward_end": -1.0,
    "waypoint_distance": 0.0,
    "waypoint_moves": 4,  # rows before 26: the planner's straight moves only
    "clearance_reward": 0.0,
    "clearance": 0.25,
}
LEVERS = {  # what the generalist's settings change from BEFORE
    "laser_range": 3.5,
    "turn_speed": 2.0,
    "max_steps": 500,
    "collision_reward": -10.0,
    "step_reward_start": -0.1,
    "step_reward_end": -0.2,
}
# the network before the wider one of rows 18-20
SMALL_NET = {"hidden_sizes": (512, 256, 128, 64), "compute_dtype": "float32"}
WIDE = {"num_envs": 16384, "rollout_length": 16, "num_minibatches": 8, "num_epochs": 2, **SMALL_NET}
DEEP = {"num_envs": 4096, "rollout_length": 32, "num_minibatches": 32, "num_epochs": 4, **SMALL_NET}
STEPS = {"total_timesteps": 100_000_000, "td_lambda": 0.9, "log_interval": 4_000_000}
NAV = {**BEFORE, **LEVERS, "waypoint_distance": 1.0}  # RobotNav-v0 before the clearance reward
# 8,192 envs x 32 steps, 64 minibatches x 4 epochs, 100M steps (row 13's shape)
NAV_TRAIN = {**DEEP, **STEPS, "num_envs": 8192, "num_minibatches": 64, "gamma": 0.99, "lr": 1e-3}
CLEAR = {"clearance_reward": -1.0, "clearance": 0.1}
# row 19's network at 100M steps (10 logging intervals of 40 iterations), then fewer, larger
# minibatches: the update is bound by the latency of each gradient step, not by its size
WIDE_NET = {
    **NAV_TRAIN,
    "hidden_sizes": (1024, 512, 256),
    "compute_dtype": "bfloat16",
    "total_timesteps": 104_857_600,
    "log_interval": 10_485_760,
}
FEWER = {**WIDE_NET, "num_minibatches": 16, "lr": 2e-3}  # 64 gradient steps of 16,384
# (label, env overrides, training overrides)
ROWS: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    (
        "before, 16 updates per iteration",
        BEFORE,
        {**WIDE, **STEPS, "gamma": 0.95, "td_lambda": 0.65},
    ),
    ("+ gamma 0.99", BEFORE, {**WIDE, **STEPS, "gamma": 0.99, "td_lambda": 0.65}),
    ("+ lambda 0.9 (gamma 0.95)", BEFORE, {**WIDE, **STEPS, "gamma": 0.95}),
    (
        "+ levers (3.5 m lidar, 0.2 rad turns, rewards)",
        {**BEFORE, **LEVERS},
        {**WIDE, **STEPS, "gamma": 0.99},
    ),
    (
        "+ levers but 0.5 rad turns",
        {**BEFORE, **LEVERS, "turn_speed": 5.0},
        {**WIDE, **STEPS, "gamma": 0.99},
    ),
    (
        "+ levers but a 14 m lidar",
        {**BEFORE, **LEVERS, "laser_range": LASER_SCALE},
        {**WIDE, **STEPS, "gamma": 0.99},
    ),
    ("before, 128 updates per iteration", BEFORE, {**DEEP, **STEPS, "gamma": 0.95}),
    ("+ levers, 128 updates", {**BEFORE, **LEVERS}, {**DEEP, **STEPS, "gamma": 0.99}),
    (
        "+ levers, 16,384 envs, 256 updates",
        {**BEFORE, **LEVERS},
        {**WIDE, **STEPS, "num_minibatches": 64, "num_epochs": 4, "gamma": 0.99},
    ),
    (
        "before + waypoint 4 cells, 128 updates",
        {**BEFORE, "waypoint_distance": 2.0},
        {**DEEP, **STEPS, "gamma": 0.95},
    ),
    (
        "+ levers + waypoint 4 cells",
        {**BEFORE, **LEVERS, "waypoint_distance": 2.0},
        {**DEEP, **STEPS, "gamma": 0.99},
    ),
    (
        "+ levers + waypoint 2 cells (RobotNav-v0)",
        {**BEFORE, **LEVERS, "waypoint_distance": 1.0},
        {**DEEP, **STEPS, "gamma": 0.99},
    ),
    (
        "RobotNav-v0, 200M steps",
        {**BEFORE, **LEVERS, "waypoint_distance": 1.0},
        {**DEEP, **STEPS, "gamma": 0.99, "total_timesteps": 200_000_000, "log_interval": 8_000_000},
    ),
    (
        "RobotNav-v0, 8,192 envs, 200M steps",
        {**BEFORE, **LEVERS, "waypoint_distance": 1.0},
        {
            **DEEP,
            **STEPS,
            "num_envs": 8192,
            "num_minibatches": 64,
            "gamma": 0.99,
            "total_timesteps": 200_000_000,
            "log_interval": 8_000_000,
        },
    ),
    (
        "RobotNav-v0 + clearance reward -1 within 0.25 m",
        {**BEFORE, **LEVERS, "waypoint_distance": 1.0, "clearance_reward": -1.0},
        {**DEEP, **STEPS, "gamma": 0.99},
    ),
    (
        "RobotNav-v0 + clearance reward -3 within 0.25 m",
        {**BEFORE, **LEVERS, "waypoint_distance": 1.0, "clearance_reward": -3.0},
        {**DEEP, **STEPS, "gamma": 0.99},
    ),
    (
        "RobotNav-v0 + clearance reward -1 within 0.5 m",
        {**BEFORE, **LEVERS, "waypoint_distance": 1.0, "clearance_reward": -1.0, "clearance": 0.5},
        {**DEEP, **STEPS, "gamma": 0.99},
    ),
    ("RobotNav-v0 + clearance reward -1 within 0.1 m, 8,192 envs", {**NAV, **CLEAR}, NAV_TRAIN),
    (
        "+ a 1024-512-256 network",
        {**NAV, **CLEAR},
        {**NAV_TRAIN, "hidden_sizes": (1024, 512, 256)},
    ),
    (
        "+ a 1024-512-256 network in bfloat16, 300M steps",
        {**NAV, **CLEAR},
        {
            **NAV_TRAIN,
            "hidden_sizes": (1024, 512, 256),
            "compute_dtype": "bfloat16",
            "total_timesteps": 300_000_000,
            "log_interval": 10_000_000,
        },
    ),
    ("row 19's network, 100M steps", {**NAV, **CLEAR}, WIDE_NET),
    ("+ 16 minibatches of 16,384", {**NAV, **CLEAR}, {**WIDE_NET, "num_minibatches": 16}),
    ("+ 16 minibatches of 16,384, lr 2e-3", {**NAV, **CLEAR}, FEWER),
    (
        "+ 32 minibatches of 8,192 x 2 epochs",
        {**NAV, **CLEAR},
        {**WIDE_NET, "num_minibatches": 32, "num_epochs": 2},
    ),
    (
        "16 minibatches, lr 2e-3, 839M steps (RobotNav-v0 PQN preset)",
        {**NAV, **CLEAR},
        {**FEWER, "total_timesteps": 838_860_800},
    ),
    (
        "row 19's network, 419M steps",
        {**NAV, **CLEAR},
        {**WIDE_NET, "total_timesteps": 419_430_400},
    ),
    (
        "row 24 + the planner's diagonal moves (RobotNav-v0)",
        {**NAV, **CLEAR, "waypoint_moves": 8},
        {**FEWER, "total_timesteps": 838_860_800},
    ),
    # collisions left are mostly corners clipped between beams 11.25 degrees apart, by moves
    # of 0.25 m where a 0.5 m corridor leaves 0.1 m each side
    (
        "row 26 + 64 lasers",
        {**NAV, **CLEAR, "waypoint_moves": 8, "num_lasers": 64},
        {**FEWER, "total_timesteps": 838_860_800},
    ),
    (
        "row 26 at 1.5 m/s (0.15 m a step), 800 steps",
        {**NAV, **CLEAR, "waypoint_moves": 8, "speed": 1.5, "max_steps": 800},
        {**FEWER, "total_timesteps": 838_860_800},
    ),
    (
        "row 28 + the fused LayerNorm (RobotNav-v0 PQN preset)",
        {**NAV, **CLEAR, "waypoint_moves": 8, "speed": 1.5, "max_steps": 800},
        {**FEWER, "total_timesteps": 838_860_800, "fused_layer_norm": True},
    ),
]
# rows from 20 train from jax.random.split(key(0), 1), the key of the first of a batch of seeds
SPLIT_KEY_ROWS = 20
# rows before 29 ran flax's LayerNorm, before the preset fused it
FUSED_ROWS = 29
TEST_KEY = 1234


def families(config: TrainConfig) -> list[Family]:
    held_out = Family("held-out", "own", {"maze_seed": 1_000_003, "num_layouts": 1000})
    return [Family("training bank", "own"), held_out, *default_families(config)[1:]]


def train_one(config: TrainConfig, keys: jax.Array) -> tuple[Trainer, Any, dict[str, Any]]:
    """Train ``config`` once per key of ``keys``, vmapped; ``(trainer, final states with a
    leading key axis, timing)``, the timing's compile and training seconds apart, with the env
    steps of one run, the steps per second of all and how many runs diverged."""
    trainer = Trainer(config)
    # vmapped over a batch of one key (rows 0-19 used jit(train)): with the optimizer state of
    # a leaf per layer that ran 1.43x as fast on one H100; with today's preset the two run
    # alike (train_vmap_h100 in docs/results-history.md)
    train = jit_training(jax.vmap(trainer.train))
    t0 = time.perf_counter()
    compiled = train.lower(keys).compile()
    t1 = time.perf_counter()
    state, metrics = jax.block_until_ready(compiled(keys))
    t2 = time.perf_counter()
    steps = int(metrics["env_steps"][0, -1])
    timing = {
        "compile_s": round(t1 - t0, 1),
        "train_s": round(t2 - t1, 2),
        "env_steps": steps,
        "env_steps_per_s": steps * len(keys) / (t2 - t1),
        "diverged": int(np.sum(state.diverged)),
    }
    return trainer, state, timing


def run_row(index: int, episodes: int) -> dict[str, Any]:
    label, env_kwargs, overrides = ROWS[index]
    if index < FUSED_ROWS:
        overrides = {"fused_layer_norm": False, **overrides}
    config = TrainConfig.for_env(
        "RobotNav-v0", algo="pqn", env_kwargs=env_kwargs, eval_episodes=0, **overrides
    )
    keys = jax.random.key(0)[None]
    if index >= SPLIT_KEY_ROWS:
        keys = jax.random.split(jax.random.key(0), 1)
    trainer, states, timing = train_one(config, keys)
    state = jax.tree.map(lambda x: x[0], states)
    row: dict[str, Any] = {
        "row": index,
        "label": label,
        "env_kwargs": env_kwargs,
        "train": overrides,
        **timing,
        "tests": {},
    }
    policy = trainer.greedy_policy(state.params)
    for family in families(config):
        env_id, kwargs = family.for_run(config)
        env, params = jaxnav.make(env_id, **kwargs)
        out = run_episodes(
            env, params, policy, jax.random.key(TEST_KEY), episodes, params.max_steps_in_episode
        )
        row["tests"][family.name] = {
            "success": float(np.mean(out["success"])),
            "collision": float(np.mean(out["collision"])),
        }
    return row


def markdown(rows: list[dict[str, Any]]) -> str:
    names = list(rows[0]["tests"])
    head = "| row | setting | train s | env steps/s | " + " | ".join(names) + " |"
    lines = [head, "|" + "---|" * (4 + len(names))]
    for r in rows:
        cells = [f"{t['success']:.3f} / {t['collision']:.3f}" for t in r["tests"].values()]
        lines.append(
            f"| {r['row']} | {r['label']} | {r['train_s']:.1f} | {r['env_steps_per_s']:,.0f} | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines) + (
        "\n\nCells: greedy success / collision rate. Rows 0-25 looked 2 cells ahead on the maze"
        " files (the lookahead was then counted in cells of each maze; see the script's"
        " docstring).\n"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.generalist_sweep")
    p.add_argument("--rows", default=",".join(map(str, range(len(ROWS)))))
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/generalist_sweep.jsonl"))
    args = p.parse_args(argv)
    try:
        rows = [int(r) for r in args.rows.split(",")]
        if not rows or not all(0 <= r < len(ROWS) for r in rows) or args.episodes < 1:
            raise ValueError
    except ValueError:
        p.exit(2, f"{p.prog}: --rows {args.rows!r} / --episodes {args.episodes}: rows are "
               f"0..{len(ROWS) - 1}, episodes >= 1\n")  # fmt: skip
    done = []
    for index in rows:
        row = run_row(index, args.episodes) | {"machine": machine_info()}
        print(json.dumps(row), flush=True)
        with args.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        done.append(row)
    all_rows = [json.loads(line) for line in args.out.read_text().splitlines() if line.strip()]
    args.out.with_suffix(".md").write_text(markdown(all_rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
