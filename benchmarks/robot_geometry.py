"""Micro-benchmark of the robot geometry (jaxnav/envs/robot/geometry.py), per env step.

    python -m benchmarks.robot_geometry [--num-envs 4096] [--walls 24,40] [--steps 50]
        [--rounds 5] [--substeps N] [--out benchmarks/results/robot_geometry.json]

Every env has its own walls (``float32[E, W, 2]`` centres and half-sizes, ``bool[E, W]``
active; the functions are vmapped over envs, walls included). A layout is a 5 m x 5 m arena:
4 boundary walls plus ``W - 4`` random interior walls 0.1 m thick (half-size 0.05 m) and
0.3-1.5 m long, about 1 in 8 slots inactive (padding). Robots start at random poses, radius
0.15 m, commands up to 1 m/s and 2 rad/s held for dt = 0.25 s.

Rows, each one jitted ``lax.scan`` of ``--steps`` steps over all envs (a scan so that the
per-call dispatch is amortized; the carry changes every step so nothing is hoisted):

- ``lasers``: the paper's 7 lasers (``geometry.lasers``), the pose nudged each step.
- ``kinematic step``: ``geometry.move_with_walls`` with ``--substeps`` sub-steps (default
  ``min_substeps(1 m/s, 0.25 s, 0.05 m)`` = 6: no skipping through the 0.1 m walls).
- ``step + lasers``: both, what an env step of the kinematic backend computes.

"compile s" is ``jit(f).lower(...).compile()`` alone; "env-steps/s" is num_envs * steps over
the median of ``--rounds`` timed runs after a warm-up, rows timed in turn round by round.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.common import compile_timed, machine_info, time_in_turn, write_results
from jaxnav.envs.robot import geometry as g

DEFAULT_OUT = Path("benchmarks/results/robot_geometry.json")
ARENA = 5.0
WALL_HALF = 0.05
RADIUS = 0.15
MAX_RANGE = 5.0
DT = 0.25
V_MAX, OMEGA_MAX = 1.0, 2.0
KINDS = ("lasers", "kinematic step", "step + lasers")


def make_walls(num_envs: int, num_walls: int, seed: int) -> tuple[np.ndarray, ...]:
    """Per-env walls: 4 boundary walls of the arena, then random thin interior walls."""
    if num_walls < 4:
        raise ValueError(f"--walls {num_walls}: need at least the 4 boundary walls")
    rng = np.random.default_rng(seed)
    a, t = ARENA, WALL_HALF
    boundary_c = np.array([[a / 2, -t], [a / 2, a + t], [-t, a / 2], [a + t, a / 2]])
    boundary_h = np.array([[a / 2 + 2 * t, t], [a / 2 + 2 * t, t], [t, a / 2], [t, a / 2]])
    k = num_walls - 4
    length = rng.uniform(0.15, 0.75, (num_envs, k))
    vertical = rng.random((num_envs, k)) < 0.5
    half = np.stack([np.where(vertical, t, length), np.where(vertical, length, t)], axis=-1)
    center = rng.uniform(0.5, a - 0.5, (num_envs, k, 2))
    active = np.concatenate(
        [np.ones((num_envs, 4), bool), rng.random((num_envs, k)) < 0.875], axis=1
    )
    center = np.concatenate([np.broadcast_to(boundary_c, (num_envs, 4, 2)), center], axis=1)
    half = np.concatenate([np.broadcast_to(boundary_h, (num_envs, 4, 2)), half], axis=1)
    center = np.where(active[..., None], center, 1e4)  # parked padding, as mazes.py does
    half = np.where(active[..., None], half, 1e-3)
    return center.astype(np.float32), half.astype(np.float32), active


def build(kind: str, substeps: int) -> Callable[..., Any]:
    """One env's step for a row: ``(pose, cmd, center, half, active) -> (pose, checksum)``."""
    angles = g.laser_angles()

    def lasers(pose, cmd, c, h, a):
        ranges = g.lasers(pose, *g.box_bounds(c, h, a), angles, MAX_RANGE)
        nudged = pose + jnp.array([1e-3, -1e-3, 1e-2], jnp.float32)  # a new pose every step
        return nudged, ranges.sum()

    def step(pose, cmd, c, h, a):
        new, collided, pen = g.move_with_walls(pose, cmd[0], cmd[1], DT, RADIUS, c, h, a, substeps)
        return new, collided.astype(jnp.float32) + pen

    def both(pose, cmd, c, h, a):
        new, checksum = step(pose, cmd, c, h, a)
        return new, checksum + g.lasers(new, *g.box_bounds(c, h, a), angles, MAX_RANGE).sum()

    return {"lasers": lasers, "kinematic step": step, "step + lasers": both}[kind]


def prepare(kind: str, num_envs: int, num_walls: int, steps: int, substeps: int) -> dict:
    one = jax.vmap(build(kind, substeps))
    center, half, active = (jnp.asarray(x) for x in make_walls(num_envs, num_walls, seed=0))
    rng = np.random.default_rng(1)
    lo, hi = [0.3, 0.3, -np.pi], [ARENA - 0.3, ARENA - 0.3, np.pi]
    pose = jnp.asarray(rng.uniform(lo, hi, (num_envs, 3)), jnp.float32)
    cmds = jnp.asarray(
        rng.uniform([-V_MAX, -OMEGA_MAX], [V_MAX, OMEGA_MAX], (steps, num_envs, 2)), jnp.float32
    )

    def rollout(pose, cmds, center, half, active):
        def body(carry, cmd):
            pose, total = carry
            pose, checksum = one(pose, cmd, center, half, active)
            return (pose, total + checksum.sum()), None

        return jax.lax.scan(body, (pose, jnp.zeros((), jnp.float32)), cmds)[0]

    args = (pose, cmds, center, half, active)
    run, compile_s = compile_timed(rollout, *args)
    return {
        "kind": kind,
        "num_envs": num_envs,
        "walls": num_walls,
        "rays": int(g.laser_angles().shape[0]),
        "substeps": substeps if kind != "lasers" else None,
        "steps": steps,
        "compile_s": compile_s,
        "run": run,
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--num-envs", type=int, default=4096)
    parser.add_argument("--walls", default="24,40", help="wall slots per env, comma-separated")
    parser.add_argument("--steps", type=int, default=50, help="scan length of one timed call")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument(
        "--substeps", type=int, default=g.min_substeps(V_MAX, DT, WALL_HALF), help="sub-steps"
    )
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    kinds = [k for k in args.kinds.split(",") if k]
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        parser.error(f"--kinds: unknown {unknown}; valid: {', '.join(KINDS)}")
    walls = [int(w) for w in args.walls.split(",") if w]

    rows = []
    for w in walls:
        prepared = [prepare(k, args.num_envs, w, args.steps, args.substeps) for k in kinds]
        time_in_turn(prepared, args.rounds)
        for p in prepared:
            median = statistics.median(p["run_s"])
            p["env_steps_per_s"] = p["num_envs"] * p["steps"] / median
            p["us_per_env_step"] = 1e6 * median / (p["num_envs"] * p["steps"])
            rows.append(p)

    header = "| kind | envs | walls | rays | substeps | compile s | env-steps/s | us / env-step |"
    lines = [header, "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        sub = "-" if r["substeps"] is None else str(r["substeps"])
        lines.append(
            f"| {r['kind']} | {r['num_envs']} | {r['walls']} | {r['rays']} | {sub} | "
            f"{r['compile_s']:.2f} | {r['env_steps_per_s']:,.0f} | {r['us_per_env_step']:.3f} |"
        )
    markdown = "\n".join(lines)
    print(markdown)
    result = {
        "benchmark": "robot_geometry",
        "machine": machine_info(),
        "config": {**vars(args), "out": str(args.out), "radius": RADIUS, "dt": DT},
        "results": rows,
    }
    write_results(args.out, result, markdown)
    print(f"wrote {args.out}", file=sys.stderr)
    return result


if __name__ == "__main__":
    main()
