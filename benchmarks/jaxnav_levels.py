"""The peer's benchmark: a policy on JaxNav's levels under SFL's evaluation protocol, beside
the figures SFL published for its own method and the baselines.

    python -m benchmarks.jaxnav_levels --run RUN [--levels 10000] [--episodes-per-level 10]
        [--maze-seed 1000003] [--radius 0.25] [--chunk-levels 1000] [--seed 0] \
        [--policy trained|shielded]
    python -m benchmarks.jaxnav_levels --pretrained NAME|FILE.npz ...   # an exported policy
    python -m benchmarks.jaxnav_levels --random ...   # the random agent (a smoke check)

Levels: ``--levels`` levels of ``RobotJaxNav-v0`` (``jaxnav/envs/robot/jaxnav_levels.py``)
drawn from ``--maze-seed``, by default ``experiments.HELD_OUT_MAZE_SEED``: streams no training
bank of seed 0 uses. Protocol (``jaxnav.evaluate.levels``): ``--episodes-per-level`` episodes
of every level on key A and again on an independent key B (both from ``--seed``); success,
collision and timeout rates over all episodes of both keys; CVaR-10% and CVaR-1% of the
per-level success, the worst levels picked on A and measured on B. Each training seed of the
run is evaluated on the same episodes, greedy or, with ``--policy shielded``, through the lidar
collision monitor (``jaxnav.evaluate.shielded_policy``); the table gives each seed and their
mean.

A policy trained on another env id keeps its observation settings (``sensor_overrides``,
overrides included) on RobotJaxNav-v0's levels, robot, speeds and time limit, without the
planner's waypoint: the benchmark is map-free, as JaxNav's robot. A waypoint planned on the
robot's own lidar map (``lidar_map``) is map-free and stays. A policy whose network reads
observations of another size is refused in one line (exit 2), as is any bad flag.

Levels are played ``--chunk-levels`` at a time (one compiled program, the last chunk padded),
so 10,000 levels x 10 episodes fit on a GPU (``--chunk-levels 10000``) and small sizes run on
a CPU. Writes ``benchmarks/results/jaxnav_levels.{json,md}`` (``--out``), each whole or not at
all.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from benchmarks.common import machine_info, machine_text, write_results
from jaxnav import export, pretrained, run_dir
from jaxnav.cli import HelpFormatter, Parser, UsageError, fail
from jaxnav.evaluate import Policy, format_value, policy_maker, random_policy
from jaxnav.evaluate.levels import CVAR_ALPHAS, run_level_episodes, sfl_summary
from jaxnav.experiments import HELD_OUT_MAZE_SEED
from jaxnav.registration import env_config, make
from jaxnav.safe_io import check_output_file

ENV = "RobotJaxNav-v0"
DEFAULT_OUT = Path("benchmarks/results/jaxnav_levels.json")
# SFL's single-robot JaxNav results on its 10,000 held-out levels (the paper, Rutherford et al.
# 2024, "No Regrets: Investigating and Improving Regret Approximations for Curriculum
# Discovery", and its repository's evaluation data): success rate and CVaR-10%
PUBLISHED = {
    "SFL": (0.980, 0.80),
    "DR": (0.965, 0.65),
    "PLR": (0.967, 0.68),
    "ACCEL": (0.959, 0.59),
}
# how --policy is named in the tables
POLICY_LABEL = {"trained": "greedy", "shielded": "greedy, shielded"}
COLUMNS = ("success_rate", "cvar_10", "cvar_1", "collision_rate", "timeout_rate")


def parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="python -m benchmarks.jaxnav_levels",
        description="A policy on JaxNav's levels under SFL's evaluation protocol.",
        formatter_class=HelpFormatter,
    )
    who = p.add_mutually_exclusive_group(required=True)
    who.add_argument("--run", type=Path, help="a trained run directory (its greedy policy)")
    who.add_argument(
        "--pretrained", metavar="NAME|FILE", help="a shipped policy or an exported npz (greedy)"
    )
    who.add_argument("--random", action="store_true", help="the random agent")
    p.add_argument("--levels", type=int, default=10_000, help="held-out levels")
    p.add_argument("--episodes-per-level", type=int, default=10, help="per level and key")
    p.add_argument(
        "--maze-seed", type=int, default=HELD_OUT_MAZE_SEED, help="the levels' seed (0 trains)"
    )
    p.add_argument("--radius", type=float, default=0.25, help="the robot's radius (m)")
    p.add_argument("--chunk-levels", type=int, default=1000, help="levels played at a time")
    p.add_argument("--seed", type=int, default=0, help="seed of the two evaluation keys")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output JSON (and .md beside)")
    p.add_argument(
        "--policy",
        choices=("trained", "shielded"),
        default="trained",
        help="greedy, or greedy through the lidar collision monitor",
    )
    return p


def check_args(args: argparse.Namespace) -> None:
    """``ValueError`` naming the first bad flag value."""
    for flag, lo, hi in (
        ("levels", 1, 100_000),
        ("episodes_per_level", 1, 10_000),
        ("chunk_levels", 1, 100_000),
        ("maze_seed", 1, 2**32 - 1),
        ("seed", 0, 2**31 - 1),
    ):
        v = getattr(args, flag)
        if not lo <= v <= hi:
            name = "--" + flag.replace("_", "-")
            raise ValueError(f"{name} {v}: must be an integer in [{lo}, {hi}]")
    if not 0 < args.radius < 0.5:
        raise ValueError(f"--radius {args.radius}: must be in (0, 0.5) m (a 1 m cell)")
    if args.random and args.policy == "shielded":
        raise ValueError("--policy shielded: shields a trained policy, not --random")
    if args.run is not None and not args.run.is_dir():
        raise ValueError(f"--run {args.run}: not a run directory")
    check_output_file(args.out)
    check_output_file(args.out.with_suffix(".md"), "--out (markdown)")


def sensor_overrides(env_id: str, env_kwargs: dict[str, Any], source: str) -> dict[str, Any]:
    """The settings that shape the observation of a policy trained on ``env_id`` with
    ``env_kwargs`` (``run_dir.OBSERVATION_FIELDS``, and ``lidar_map`` where set: a waypoint
    from the robot's own map is map-free), as RobotJaxNav-v0 overrides; ``ValueError`` naming
    ``source`` if that env is no robot env or its waypoint comes from the maze's map."""
    trained = dataclasses.asdict(env_config(env_id, **env_kwargs))
    if "lidar_map" not in trained:
        raise ValueError(f"{source}: trained on {env_id}, not a robot env")
    if trained["waypoint_distance"] and not trained["lidar_map"]:
        raise ValueError(
            f"{source}: reads a waypoint planned on the maze's map; the benchmark is map-free"
        )
    own_map = {"lidar_map": trained["lidar_map"]} if trained["lidar_map"] else {}
    return {f: trained[f] for f in run_dir.OBSERVATION_FIELDS if f in trained} | own_map


def policies(args: argparse.Namespace, env_kwargs: dict[str, Any]) -> tuple[Any, Any, Any, Any]:
    """``(env, env params, policy of params, stacked params or None)`` for the run or the
    random agent on the levels."""
    if args.random:
        env, params = make(ENV, **env_kwargs)
        return env, params, (lambda p: random_policy(env.num_actions)), None
    if args.pretrained is not None:
        source = f"--pretrained {args.pretrained}"
        policy = pretrained.load_source(args.pretrained, source)
        meta = policy.metadata
        kwargs = sensor_overrides(meta["env_id"], meta["env_kwargs"], source) | env_kwargs
        trainer, seed_params = export.to_trainer(policy, ENV, kwargs)
    else:
        config = run_dir.load_config(args.run)
        kwargs = sensor_overrides(config.env, config.env_kwargs, f"--run {args.run}")
        kwargs |= env_kwargs
        _, trainer, seed_params = run_dir.load_run_on(args.run, ENV, kwargs)
    env, params = trainer.env, trainer.env_params
    return env, params, policy_maker(args.policy, trainer, env, params), seed_params


def policy_name(args: argparse.Namespace) -> str:
    if args.random:
        return "the random agent"
    if args.pretrained is not None:
        return f"policy {args.pretrained} ({POLICY_LABEL[args.policy]})"
    return f"run {args.run} ({POLICY_LABEL[args.policy]})"


def chunk_program(
    env: Any, params: Any, make_policy: Any, episodes_per_level: int
) -> Callable[[Any, jax.Array, np.ndarray], dict[str, jax.Array]]:
    """``(policy params, key, levels) -> outcomes``: ``run_level_episodes`` compiled once for
    every seed, key and chunk of one size."""
    max_steps = int(params.max_steps_in_episode)

    @jax.jit
    def one_chunk(p: Any, key: jax.Array, levels: jax.Array) -> dict[str, jax.Array]:
        policy: Policy = make_policy(p)
        return run_level_episodes(env, params, policy, key, levels, episodes_per_level, max_steps)

    return one_chunk


def evaluate_levels(
    program: Callable[[Any, jax.Array, np.ndarray], dict[str, jax.Array]],
    policy_params: Any,
    key: jax.Array,
    num_levels: int,
    episodes_per_level: int,
    chunk_levels: int,
    progress: Callable[[int], None] | None = None,
) -> dict[str, np.ndarray]:
    """Per-episode outcomes of every level ``0 .. num_levels - 1`` of the env's bank, played
    ``chunk_levels`` at a time by ``program`` (``chunk_program``; the last chunk padded with
    level 0, whose padding episodes are dropped); ``progress`` gets the levels done after each
    chunk."""
    chunk = min(chunk_levels, num_levels)
    parts: list[dict[str, np.ndarray]] = []
    for start in range(0, num_levels, chunk):
        valid = min(chunk, num_levels - start)
        levels = np.zeros(chunk, np.int32)
        levels[:valid] = np.arange(start, start + valid)
        out = jax.device_get(program(policy_params, key, levels))
        keep = np.arange(chunk * episodes_per_level) % chunk < valid
        parts.append({k: np.asarray(v)[keep] for k, v in out.items()})
        if progress is not None:
            progress(start + valid)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def say_progress(label: str, total: int, done: int) -> None:
    """A line on stderr: how many of ``total`` levels ``label``'s evaluation has played."""
    print(f"{label}: {done:,}/{total:,} levels", file=sys.stderr, flush=True)


def markdown(result: dict[str, Any]) -> str:
    """The table: each seed, their mean, and SFL's published figures."""
    lines = [
        "# JaxNav's levels, SFL's evaluation protocol\n",
        f"{result['env']}: {result['levels']:,} levels of maze_seed {result['maze_seed']}, "
        f"{result['episodes_per_level']} episodes per level on each of two keys (seed "
        f"{result['seed']}); robot radius {result['radius']} m. Success, collision and timeout "
        "over all episodes of both keys; CVaR: the worst levels picked on key A, their success "
        f"measured on key B. {result['policy']}; {machine_text(result['machine'])}.\n",
        "| policy | success | CVaR-10% | CVaR-1% | collision | timeout |",
        "|---|---|---|---|---|---|",
    ]
    for row in result["rows"]:
        cells = " | ".join(format_value(row.get(c)) for c in COLUMNS)
        lines.append(f"| {row['name']} | {cells} |")
    for name, (success, cvar10) in PUBLISHED.items():
        lines.append(f"| {name} (published) | {success:.3f} | {cvar10:.2f} | n/a | n/a | n/a |")
    lines.append(
        '\nPublished: Rutherford et al. 2024, "No Regrets: Investigating and Improving Regret '
        'Approximations for Curriculum Discovery" (SFL), single-robot JaxNav, and its '
        "repository's evaluation data. Their robot is a 0.5 m square with continuous "
        "commands up to 1 m/s and 0.6 rad/s and a 200-beam lidar; ours a disc "
        f"({result['radius']} m) with 4 discrete actions (RobotJaxNav-v0's docstring, "
        "jaxnav/registration.py)."
    )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    prog = "benchmarks.jaxnav_levels"
    try:
        args = parser().parse_args(argv)
        check_args(args)
        env_kwargs = {
            "maze_seed": args.maze_seed,
            "num_layouts": args.levels,
            "radius": args.radius,
            "radius_range": None,  # the one robot size asked for, whatever the run drew
        }
        t0 = time.perf_counter()
        env, params, make_policy, seed_params = policies(args, env_kwargs)
        bank_s = time.perf_counter() - t0
    except (UsageError, ValueError, FileNotFoundError) as e:
        return fail(prog, str(e))
    seeds = 1 if seed_params is None else jax.tree.leaves(seed_params)[0].shape[0]
    key_a, key_b = (jax.random.fold_in(jax.random.key(args.seed), i) for i in (0, 1))
    program = chunk_program(env, params, make_policy, args.episodes_per_level)
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for s in range(seeds):
        p = None if seed_params is None else jax.tree.map(lambda x, s=s: x[s], seed_params)
        outcomes = []
        for name, k in (("A", key_a), ("B", key_b)):
            label = f"seed {s}, key {name}" if seeds > 1 else f"key {name}"
            progress = functools.partial(say_progress, label, args.levels)
            outcomes.append(
                evaluate_levels(
                    program, p, k, args.levels, args.episodes_per_level, args.chunk_levels, progress
                )
            )
        row = sfl_summary(*outcomes, args.levels, CVAR_ALPHAS)
        row["name"] = "random" if args.random else args.pretrained or f"seed {s}"
        rows.append(row)
        print(
            f"{row['name']}: success {row['success_rate']:.3f}, CVaR-10% {row['cvar_10']:.3f},"
            f" CVaR-1% {row['cvar_1']:.3f}",
            flush=True,
        )
    eval_s = time.perf_counter() - t0
    if len(rows) > 1:
        mean = {c: float(np.mean([r[c] for r in rows])) for c in COLUMNS}
        rows.append({"name": f"mean of {len(rows)} seeds", **mean})
    config = dataclasses.asdict(env.config)
    result = {
        "env": ENV,
        "policy": policy_name(args),
        "levels": args.levels,
        "episodes_per_level": args.episodes_per_level,
        "maze_seed": args.maze_seed,
        "seed": args.seed,
        "radius": args.radius,
        "chunk_levels": args.chunk_levels,
        "env_config": config,
        "bank_and_load_s": bank_s,
        "evaluate_s": eval_s,
        "rows": rows,
        "published": {k: {"success_rate": s, "cvar_10": c} for k, (s, c) in PUBLISHED.items()},
        "machine": machine_info(),
    }
    text = markdown(result)
    write_results(args.out, result, text)
    print(text)
    print(f"wrote {args.out} and {args.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
