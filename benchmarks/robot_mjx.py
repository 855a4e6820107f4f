"""Throughput of the MJX robot backend (jaxnav/envs/robot/mjx_backend.py), per control step.

    python -m benchmarks.robot_mjx [--num-envs 256,4096] [--slots 24] [--steps 20]
        [--rounds 3] [--out benchmarks/results/robot_mjx.json]

Every env has its own walls: a bank of 64 random 10 x 10 m mazes (``random_maze_bank``, 1 m
cells, ``--slots`` wall slots), env ``i`` using maze ``i % 64``, batched into the model's
``geom_pos`` / ``geom_size`` / ``geom_rbound`` (``MjxRobot.batch_with_walls``). Robots start at
a placement cell with a random heading; each control step (0.1 s = 5 MJX substeps of 0.02 s)
takes uniform random commands ``v`` in [-1, 1] m/s and ``omega`` in [-2, 2] rad/s, so robots
meet walls. One jitted ``lax.scan`` of ``--steps`` control steps over all envs is timed;
"compile s" is ``jit(...).lower(...).compile()`` alone; "steps/s" is envs * steps over the
median of ``--rounds`` timed runs after a warm-up. Only the physics step: no lasers, reward
or resets.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.common import (
    compile_timed,
    machine_info,
    time_in_turn,
    write_results,
)
from jaxnav.envs.robot import mazes
from jaxnav.envs.robot.mjx_backend import MjxRobot
from jaxnav.host import package_version

DEFAULT_OUT = Path("benchmarks/results/robot_mjx.json")
RADIUS = 0.15
NUM_MAZES = 64


def prepare(robot: MjxRobot, bank: mazes.MazeBank, num_envs: int, steps: int) -> dict:
    idx = np.arange(num_envs) % bank.num_mazes
    walls = jax.tree.map(lambda x: x[idx], bank.walls)
    models = robot.batch_with_walls(walls)
    rng = np.random.default_rng(0)
    cell = rng.integers(np.asarray(bank.num_free)[idx])
    xy = np.asarray(bank.free_xy)[idx, cell]
    poses = jnp.asarray(np.concatenate([xy, rng.uniform(-np.pi, np.pi, (num_envs, 1))], -1))
    axes = robot.model_axes
    data = jax.jit(jax.vmap(robot.init, in_axes=(axes, 0)))(models, poses.astype(jnp.float32))
    vstep = jax.vmap(robot.step, in_axes=(axes, 0, 0, 0))

    def rollout(models, data, key):
        def body(carry, k):
            d, total = carry
            cmd = jax.random.uniform(k, (2, num_envs), minval=-1.0, maxval=1.0)
            d, pose, collided, pen = vstep(models, d, cmd[0], 2.0 * cmd[1])
            return (d, total + collided.sum() + pen.sum() + pose.sum()), None

        keys = jax.random.split(key, steps)
        return jax.lax.scan(body, (data, jnp.zeros((), jnp.float32)), keys)[0]

    args = (models, data, jax.random.key(1))
    run, compile_s = compile_timed(rollout, *args)
    return {"num_envs": num_envs, "steps": steps, "compile_s": compile_s, "run": run}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--num-envs", default="256,4096", help="comma-separated env counts")
    parser.add_argument("--slots", type=int, default=24, help="wall slots per env")
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    env_counts = [int(n) for n in args.num_envs.split(",") if n]

    robot = MjxRobot(args.slots, RADIUS, (10.0, 10.0))
    bank = mazes.stack_mazes(mazes.random_maze_bank(NUM_MAZES, num_slots=args.slots), args.slots)
    rows = [prepare(robot, bank, n, args.steps) for n in env_counts]
    time_in_turn(rows, args.rounds)
    for r in rows:
        median = statistics.median(r["run_s"])
        r["steps_per_s"] = r["num_envs"] * r["steps"] / median
        r["us_per_env_step"] = 1e6 * median / (r["num_envs"] * r["steps"])

    lines = [
        "| envs | walls | substeps | compile s | control steps/s | us / env-step |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['num_envs']} | {args.slots} | {robot.substeps} | {r['compile_s']:.1f} | "
            f"{r['steps_per_s']:,.0f} | {r['us_per_env_step']:.1f} |"
        )
    markdown = "\n".join(lines)
    print(markdown)
    result = {
        "benchmark": "robot_mjx",
        "machine": {**machine_info(), "mujoco_mjx": package_version("mujoco-mjx")},
        "config": {
            **vars(args),
            "out": str(args.out),
            "radius": RADIUS,
            "timestep": robot.timestep,
            "substeps": robot.substeps,
            "num_mazes": NUM_MAZES,
        },
        "results": rows,
    }
    write_results(args.out, result, markdown)
    print(f"wrote {args.out}", file=sys.stderr)
    return result


if __name__ == "__main__":
    main()
