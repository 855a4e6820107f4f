"""Where map-free policies fail: one-cell gaps. Two measurements.

    python -m benchmarks.mapfree_gaps --policy row7.npz [--episodes 400]
    python -m benchmarks.mapfree_gaps --train-cpu [--steps 8388608]

``--policy``: an exported RobotNav-v0 policy (``benchmarks.mapfree_sweep --policies DIR``)
tested greedily on held-out corridor mazes (``maze_seed`` 1,000,003, 200 mazes, robot radius
0.15 m), its outcomes split by each maze's narrowest gap in 0.5 m cells
(``maze_algorithms.narrowest_gap``).

``--train-cpu``: PQN trained on ``examples/mazes/corridors_1cell.txt`` alone (the generalist's
env settings, the map-free sensors, 256 envs, a 256-256 network, seed 0) once per reward or
observation variant, each tested greedily on 200 episodes of that maze: does the policy learn
to pass one-cell corridors, and what changes that.

One JSON line per measurement appended to ``--out``.
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

from benchmarks.common import machine_info
from benchmarks.mapfree_sweep import GENTLE, POTENTIAL, outcome
from jaxnav.config import TrainConfig
from jaxnav.deploy.policy import Policy
from jaxnav.envs.maze_algorithms import narrowest_gap
from jaxnav.envs.robot.env import GENERALIST, MAPFREE_SENSORS
from jaxnav.evaluate import run_episodes
from jaxnav.experiments import HELD_OUT_MAZE_SEED
from jaxnav.export import to_trainer
from jaxnav.train import Trainer

MAZE_FILE = "examples/mazes/corridors_1cell.txt"
# (label, env overrides, training overrides) trained by --train-cpu
VARIANTS: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("map-free", {}, {}),
    ("map-free, crash -50", {"collision_reward": -50.0}, {}),
    (
        "map-free, step reward -0.01..-0.02, no clearance term",
        GENTLE,
        {},
    ),
    ("map-free, GRU 64", {}, {"memory": 64}),
    ("waypoint 1 m ahead", {"waypoint_distance": 1.0}, {}),
    ("map-free, odometry trail of 0.5 m cells", {"trail_cell": 0.5}, {}),
    (
        "map-free, odometry trail, step reward -0.01..-0.02, no clearance term",
        {"trail_cell": 0.5, **GENTLE},
        {},
    ),
    # the geodesic progress term charges 5 a metre of search away from the goal
    ("map-free, row 10's reward without progress", {**GENTLE, "progress_reward": 0.0}, {}),
    (
        "map-free, odometry trail, row 10's reward without progress",
        {"trail_cell": 0.5, **GENTLE, "progress_reward": 0.0},
        {},
    ),
    # progress as potential-based shaping for the learner's discount (0.99); a crash keeps its
    # potential, so it refunds nothing
    (
        "map-free, row 10's reward, potential-based progress, crash kept",
        {**GENTLE, **POTENTIAL},
        {},
    ),
    (
        "map-free, odometry trail, row 10's reward, potential-based progress, crash kept",
        {"trail_cell": 0.5, **GENTLE, **POTENTIAL},
        {},
    ),
    # the lidar collision monitor on the robot: a move it blocks is not executed
    ("map-free, collision monitor", {"shielded": True}, {}),
    ("map-free, odometry trail, collision monitor", {"trail_cell": 0.5, "shielded": True}, {}),
    # the waypoint from a planner on the robot's own lidar map, not the maze's (map-free)
    ("waypoint from its own lidar map", {"waypoint_distance": 1.0, "lidar_map": 0.25}, {}),
    (
        "waypoint from its own lidar map, odometry trail",
        {"waypoint_distance": 1.0, "lidar_map": 0.25, "trail_cell": 0.5},
        {},
    ),
]


def by_gap(policy_path: Path, episodes: int) -> dict[str, Any]:
    """The policy's outcomes on held-out corridor mazes, by narrowest gap."""
    overrides = {
        "families": ("corridors",),
        "maze_seed": HELD_OUT_MAZE_SEED,
        "num_layouts": 200,
        "radius": 0.15,
        "radius_range": None,
    }
    trainer, params = to_trainer(Policy.load(policy_path), "RobotNav-v0", overrides)
    env, env_params = trainer.env, trainer.env_params
    policy = trainer.greedy_policy(jax.tree.map(lambda x: x[0], params))
    out = run_episodes(
        env, env_params, policy, jax.random.key(1234), episodes, env_params.max_steps_in_episode
    )
    gaps = np.array([narrowest_gap(g) for g in np.asarray(env_params.bank.grid)])
    gap = gaps[np.asarray(out["layout"])]
    rows = {f"narrowest gap {g} cells": outcome(out, gap == g) | {"episodes": int((gap == g).sum())}
            for g in np.unique(gap)}  # fmt: skip
    return {"policy": policy_path.name, "episodes": episodes, "all": outcome(out), **rows}


def train_cpu(
    label: str, extra: dict[str, Any], train: dict[str, Any], steps: int
) -> dict[str, Any]:
    """PQN on the one-cell corridor maze with ``extra`` env and ``train`` training overrides,
    tested greedily."""
    maze_picking = ("maze", "num_layouts", "num_goal_cells")
    base = {k: v for k, v in GENERALIST.items() if k not in maze_picking}
    env_kwargs = {**base, **MAPFREE_SENSORS, "maze_file": MAZE_FILE, **extra}
    config = TrainConfig.for_env(
        "RobotMaze-v0", algo="pqn", env_kwargs=env_kwargs, num_envs=256, rollout_length=16,
        num_minibatches=8, num_epochs=2, hidden_sizes=(256, 256), compute_dtype="float32",
        fused_layer_norm=False, total_timesteps=steps, log_interval=steps // 4, gamma=0.99,
        td_lambda=0.9, eps_decay_steps=steps // 4, lr=1e-3, eval_episodes=0, **train,
    )  # fmt: skip
    trainer = Trainer(config)
    t0 = time.perf_counter()
    state, _ = jax.block_until_ready(jax.jit(trainer.train)(jax.random.key(0)))
    train_s = time.perf_counter() - t0
    env, env_params = trainer.env, trainer.env_params
    out = run_episodes(
        env, env_params, trainer.greedy_policy(state.params), jax.random.key(1), 200,
        env_params.max_steps_in_episode,
    )  # fmt: skip
    return {"variant": label, "env_overrides": extra, "train": train, "env_steps": steps,
            "train_s": round(train_s, 1), "episodes": 200, **outcome(out)}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.mapfree_gaps")
    p.add_argument("--policy", type=Path, help="an exported RobotNav-v0 policy (npz)")
    p.add_argument("--episodes", type=int, default=400)
    p.add_argument("--train-cpu", action="store_true", help="train the variants on the maze")
    p.add_argument("--steps", type=int, default=8_388_608)
    p.add_argument("--variants", help="comma-separated indices of the variants (default: all)")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/mapfree_gaps.jsonl"))
    args = p.parse_args(argv)
    if args.policy is None and not args.train_cpu:
        print("give --policy NPZ, --train-cpu or both", file=sys.stderr)
        return 2
    results = []
    if args.policy is not None:
        results.append(by_gap(args.policy, args.episodes))
    if args.train_cpu:
        picked = (
            range(len(VARIANTS)) if args.variants is None else map(int, args.variants.split(","))
        )
        results += [train_cpu(*VARIANTS[i], args.steps) for i in picked]
    machine = machine_info()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("a") as f:
        for r in results:
            print(json.dumps(r), flush=True)
            f.write(json.dumps(r | {"machine": machine}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
