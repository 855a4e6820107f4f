"""Map-free navigation's levers, measured: PQN on a robot env with one setting changed per row,
each trained once and tested greedily on held-out mazes (each family apart), the paper's mazes,
the maze files and, where the env exists, JaxNav-style levels at JaxNav's robot size.

    python -m benchmarks.mapfree_sweep [--rows 0,1] [--episodes 2000] [--seeds 0,1,2] \
        [--out benchmarks/results/mapfree_sweep.jsonl] [--policies DIR] \
        [--trained DIR | --pretrained NAME]

Every row is ``TrainConfig.for_env(env, algo="pqn")`` with the row's env and training
overrides, seed s (``jax.random.split(key(s), 1)``; ``--seeds``, default 0, are trained
together under ``vmap``), ``eval_episodes`` 0. "Map-free" means
``waypoint_distance=0``: the observation is the lidar, the goal's distance and bearing and,
with the row's options, the robot's previous action and radius; no waypoint, no map, no arena
coordinates; or ``lidar_map``: the waypoint comes from a planner on the robot's own lidar map.
One JSON line per row and seed (appended to ``--out``) and a markdown table beside it, with the
mean and spread over seeds of rows tested with several.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np

import jaxnav
from benchmarks.common import machine_info
from benchmarks.generalist_sweep import train_one
from jaxnav import export, pretrained
from jaxnav.config import TrainConfig
from jaxnav.deploy.policy import Policy
from jaxnav.envs.robot import generators
from jaxnav.evaluate import policy_maker, run_episodes
from jaxnav.experiments import HELD_OUT_MAZE_SEED, Family, default_families
from jaxnav.presets import GENERALIST_PQN
from jaxnav.registration import registered_envs

TEST_KEY = 1234
NAV = {k: v for k, v in GENERALIST_PQN.items() if k != "algo"}  # for ids without that preset
MAPFREE = {"waypoint_distance": 0.0}
# the goal's distance read to 16 m (past any arena here) and the previous action
ODOMETRY = {**MAPFREE, "goal_range": 16.0, "obs_last_action": True}
# JaxNav's robot and goal (radius 0.25 m, goal radius 0.3 m), on levels the policy never saw
JAXNAV_ROBOT = {"radius": 0.25, "radius_range": None, "goal_radius": 0.3, "max_steps": 500}
# the robot's size drawn per episode, and given to the policy
SIZES = {"radius_range": (0.1, 0.25), "obs_radius": True}
# every family plus JaxNav's levels in one bank, robots up to what a 0.5 m cell holds
MIXED = {
    "families": (*generators.FAMILIES, "jaxnav"),
    "radius_range": (0.1, 0.24),
    "obs_radius": True,
}
# MIXED at JaxNav's goal radius, robots up to just under a 0.5 m cell's half (the validated bound)
MIXED_GOAL = {**MIXED, "radius_range": (0.1, 0.245), "goal_radius": 0.3}
# MIXED_GOAL with JaxNav's levels in their own 1 m cells (generators' jaxnav_coarse): radii
# drawn to 0.35 m there, capped under half a cell (0.249 m) on the 0.5 m families
COARSE_JAXNAV = {
    **MIXED_GOAL,
    "families": (*generators.FAMILIES, "jaxnav_coarse"),
    "radius_range": (0.15, 0.35),
}
# a step penalty a tenth of the generalist's and no clearance term: a long search for the goal
# then costs less than a crash (-10), so a policy unsure of its way has no reason to crash
GENTLE = {"step_reward_start": -0.01, "step_reward_end": -0.02, "clearance_reward": 0.0}
# the progress term as potential-based shaping for the preset's discount (0.99)
POTENTIAL = {"progress_discount": 0.99}
# row 20's seed 1, where the command below writes it: rows 22 and 24 start from it
ROW20_SEED1 = "runs/row20/row20_seed1.npz"
MADE_BY = {
    ROW20_SEED1: "python -m benchmarks.mapfree_sweep --rows 20 --seeds 0,1 --policies runs/row20"
}
# radii the held-out mazes are tested at when a row draws the robot's size
HELD_OUT_RADII = (0.1, 0.15, 0.2)

# (label, env id, env overrides, training overrides)
ROWS: list[tuple[str, str, dict[str, Any], dict[str, Any]]] = [
    ("RobotNav-v0 preset, waypoint off", "RobotNav-v0", MAPFREE, {}),
    ("+ goal distance to 16 m, previous action", "RobotNav-v0", ODOMETRY, {}),
    ("row 1 + 8 frames", "RobotNav-v0", {**ODOMETRY, "frames": 8}, {}),
    ("row 1, 2x env steps", "RobotNav-v0", ODOMETRY, {"total_timesteps": 1_677_721_600}),
    ("row 1 on JaxNav levels, radius 0.1-0.25 m", "RobotJaxNav-v0", {**ODOMETRY, **SIZES}, NAV),
    ("waypoint on, families + JaxNav levels, radius 0.1-0.24 m", "RobotNav-v0", MIXED, {}),
    (
        "row 2 on families + JaxNav levels, radius 0.1-0.24 m, 2x env steps",
        "RobotNav-v0",
        {**ODOMETRY, "frames": 8, **MIXED},
        {"total_timesteps": 1_677_721_600},
    ),
    (
        "row 2, exploration to 1% (eps_end 0.01)",
        "RobotNav-v0",
        {**ODOMETRY, "frames": 8},
        {"eps_end": 0.01},
    ),
    ("row 2, 64 lasers", "RobotNav-v0", {**ODOMETRY, "frames": 8, "num_lasers": 64}, {}),
    # memory beyond frame stacks: a GRU between the MLP and the heads (--memory)
    ("row 1 + GRU 128", "RobotNav-v0", ODOMETRY, {"memory": 128}),
    # a step penalty whose discounted sum stays below a crash's, and no scraping cost
    (
        "row 2, step reward -0.01..-0.02, no clearance term",
        "RobotNav-v0",
        {**ODOMETRY, "frames": 8, **GENTLE},
        {},
    ),
    # JaxNav's goal radius (0.3 m) in training: at the families' 0.5 m, policies stopped 0.3-0.45
    # m from the goal and rocked there until the time limit on JaxNav's levels
    ("row 5 at goal radius 0.3 m, radius 0.1-0.245 m", "RobotNav-v0", MIXED_GOAL, {}),
    (
        "row 2 on families + JaxNav levels at goal radius 0.3 m, radius 0.1-0.245 m",
        "RobotNav-v0",
        {**ODOMETRY, "frames": 8, **MIXED_GOAL},
        {},
    ),
    # a recurrent preset with fewer sequential passes: 2 epochs of 8 minibatches (the GRU steps
    # through every minibatch's sequences one time step at a time)
    (
        "row 1 + GRU 128, 2 epochs of 8 minibatches",
        "RobotNav-v0",
        ODOMETRY,
        {"memory": 128, "num_epochs": 2, "num_minibatches": 8},
    ),
    # memory of where it has searched, from odometry: corridor mazes fail by timing out
    (
        "row 12 + odometry trail of 0.5 m cells",
        "RobotNav-v0",
        {**ODOMETRY, "frames": 8, **MIXED_GOAL, "trail_cell": 0.5},
        {},
    ),
    # SFL's idea: resets draw the bank's layouts the policy solves sometimes (--curriculum)
    (
        "row 14 + learnability curriculum",
        "RobotNav-v0",
        {**ODOMETRY, "frames": 8, **MIXED_GOAL, "trail_cell": 0.5},
        {"curriculum": "learnability"},
    ),
    # the discounted step costs stay under a crash's, and the progress term is potential-based
    # with a crash keeping its distance: no reward term makes a crash pay
    (
        "row 14, crashes never pay: row 10's reward, potential-based progress",
        "RobotNav-v0",
        {**ODOMETRY, "frames": 8, **MIXED_GOAL, "trail_cell": 0.5, **GENTLE, **POTENTIAL},
        {},
    ),
    # the waypoint policy's last failures are forward/back loops: the trail sees them
    (
        "row 11 + odometry trail of 0.5 m cells",
        "RobotNav-v0",
        {**MIXED_GOAL, "trail_cell": 0.5},
        {},
    ),
    # the lidar collision monitor on the robot in training: a move it blocks is not executed
    (
        "row 14 + collision monitor",
        "RobotNav-v0",
        {**ODOMETRY, "frames": 8, **MIXED_GOAL, "trail_cell": 0.5, "shielded": True},
        {},
    ),
    # map-free: row 17's waypoint from a planner on the robot's own lidar map, unseen cells free
    (
        "row 17, waypoint from the robot's own lidar map (map-free)",
        "RobotNav-v0",
        {**MIXED_GOAL, "trail_cell": 0.5, "lidar_map": 0.25},
        {},
    ),
    # row 19 from row 17's shipped policy, an eighth of the env steps
    (
        "row 19 fine-tuned from robotnav-sizes, 105M env steps",
        "RobotNav-v0",
        {**MIXED_GOAL, "trail_cell": 0.5, "lidar_map": 0.25},
        {"init_from": "robotnav-sizes", "total_timesteps": 104_857_600},
    ),
    # row 20 for twice the env steps
    (
        "row 19 fine-tuned from robotnav-sizes, 210M env steps",
        "RobotNav-v0",
        {**MIXED_GOAL, "trail_cell": 0.5, "lidar_map": 0.25},
        {"init_from": "robotnav-sizes", "total_timesteps": 209_715_200},
    ),
    # success falls with the radius and row 20 rarely draws large robots: row 20's seed 1
    # fine-tuned on radii from 0.15 m to just under half a 0.5 m cell
    (
        "row 20 seed 1 fine-tuned at radius 0.15-0.249 m, 105M env steps",
        "RobotNav-v0",
        {**MIXED_GOAL, "trail_cell": 0.5, "lidar_map": 0.25, "radius_range": (0.15, 0.249)},
        {"init_from": ROW20_SEED1, "total_timesteps": 104_857_600},
    ),
    # row 22's lever for the waypoint generalist: robotnav-sizes fine-tuned on large radii
    (
        "robotnav-sizes fine-tuned at radius 0.15-0.249 m, 105M env steps",
        "RobotNav-v0",
        {**MIXED_GOAL, "trail_cell": 0.5, "radius_range": (0.15, 0.249)},
        {"init_from": "robotnav-sizes", "total_timesteps": 104_857_600},
    ),
    # row 22 for twice the env steps: the shipped robotnav-mapfree (row 22) for 105M more
    (
        "robotnav-mapfree fine-tuned at radius 0.15-0.249 m, 105M env steps",
        "RobotNav-v0",
        {**MIXED_GOAL, "trail_cell": 0.5, "lidar_map": 0.25, "radius_range": (0.15, 0.249)},
        {"init_from": "robotnav-mapfree", "total_timesteps": 104_857_600},
    ),
    # JaxNav's levels in their own 1 m cells: robots past 0.25 m there (row 23's lever, wider)
    (
        "robotnav-sizes fine-tuned with 1 m-cell JaxNav levels, radius 0.15-0.35 m, 105M",
        "RobotNav-v0",
        {**COARSE_JAXNAV, "trail_cell": 0.5},
        {"init_from": "robotnav-sizes", "total_timesteps": 104_857_600},
    ),
    # the same bank for the map-free generalist
    (
        "robotnav-mapfree fine-tuned with 1 m-cell JaxNav levels, radius 0.15-0.35 m, 105M",
        "RobotNav-v0",
        {**COARSE_JAXNAV, "trail_cell": 0.5, "lidar_map": 0.25},
        {"init_from": "robotnav-mapfree", "total_timesteps": 104_857_600},
    ),
]


def families(config: TrainConfig) -> list[Family]:
    """The run's own env on held-out mazes, the paper's mazes, every maze file and, where
    registered, JaxNav-style levels at JaxNav's robot size (held out)."""
    held_out = Family("held-out", "own", {"maze_seed": HELD_OUT_MAZE_SEED, "num_layouts": 1000})
    # the paper's robot (0.15 m) on the paper's mazes and the files, whatever the run drew
    fixed = {"radius": 0.15, "radius_range": None}
    others = [Family(f.name, f.env, {**f.env_kwargs, **fixed}) for f in default_families(config)]
    out = [held_out, *others[1:]]
    if config.env_kwargs.get("radius_range") and config.env == "RobotNav-v0":
        for radius in HELD_OUT_RADII:  # capped per maze at what passes its narrowest gap
            kwargs = {**held_out.env_kwargs, "radius_range": (radius, radius)}
            out.append(Family(f"held-out, r {radius:g}", "own", kwargs))
    if "RobotJaxNav-v0" in registered_envs():
        levels = {"maze_seed": HELD_OUT_MAZE_SEED, "num_layouts": 1000, **JAXNAV_ROBOT}
        for radius in (0.1, 0.15, 0.2, 0.25):
            name = f"JaxNav levels, r {radius:g}"
            out.append(Family(name, "RobotJaxNav-v0", {**levels, "radius": radius}))
    return out


def outcome(out: dict[str, Any], mask: np.ndarray | None = None) -> dict[str, float]:
    """Success, collision and timeout rates of the episodes ``mask`` picks (all if None)."""
    keep = slice(None) if mask is None else mask
    return {
        k: float(np.mean(np.asarray(out[k])[keep])) for k in ("success", "collision", "timeout")
    }


def row_config(index: int) -> TrainConfig:
    _, env_id, env_kwargs, overrides = ROWS[index]
    return TrainConfig.for_env(
        env_id, algo="pqn", env_kwargs=env_kwargs, eval_episodes=0, **overrides
    )


def run_row(
    index: int,
    episodes: int,
    policies: Path | None = None,
    trained: Path | str | None = None,
    seeds: tuple[int, ...] = (0,),
    shielded: bool = False,
) -> list[dict[str, Any]]:
    """Train row ``index`` once per seed, the seeds vmapped together (or, with ``trained``,
    load its exported ``rowN.npz`` from that folder, or the shipped policy that ``trained``
    names (a str) on the row's env: no training time then) and test each
    policy, greedy or ``shielded`` (``jaxnav.evaluate.shielded_policy``); one result a seed.
    Seed s trains with ``jax.random.split(key(s), 1)``."""
    label, env_id, env_kwargs, overrides = ROWS[index]
    config = row_config(index)
    if trained is None:
        keys = jax.numpy.concatenate([jax.random.split(jax.random.key(s), 1) for s in seeds])
        trainer, states, timing = train_one(config, keys)
        params = [jax.tree.map(lambda x, i=i: x[i], states.params) for i in range(len(seeds))]
        timing["seeds_trained_together"] = len(seeds)
    else:  # the policy's own float32 network, as jaxnav.evaluate runs an exported policy
        seeds = (0,)
        if isinstance(trained, str):  # a shipped policy, on this row's env
            trainer, loaded = export.to_trainer(pretrained.load(trained), env_id, env_kwargs)
            tested, steps = f"pretrained {trained}", None
        else:
            trainer, loaded = export.to_trainer(Policy.load(trained / f"row{index}.npz"))
            tested, steps = "exported npz", config.total_timesteps
        params = [jax.tree.map(lambda x: x[0], loaded)]
        timing = {"train_s": None, "env_steps": steps, "tested": tested}
    rows = [
        {
            "row": index,
            "seed": seed,
            "label": label,
            "env": env_id,
            "env_kwargs": env_kwargs,
            "train": overrides,
            **timing,
            "policy": "shielded" if shielded else "greedy",
            "episodes": episodes,
            "tests": {},
        }
        for seed in seeds
    ]
    if policies is not None and trained is None:  # each seed's policy as an exported npz
        metadata = export.policy_metadata(trainer, {"benchmark": f"mapfree_sweep row {index}"})
        for seed, p in zip(seeds, params, strict=True):
            name = f"row{index}.npz" if seed == 0 else f"row{index}_seed{seed}.npz"
            arrays = export.policy_arrays(trainer.network, p)
            export.write_policy(arrays, metadata | {"seed": seed}, policies / name, "npz")
    for family in families(config):
        env_name, kwargs = family.for_run(config)
        env, env_params = jaxnav.make(env_name, **kwargs)
        policy_of = policy_maker("shielded" if shielded else "trained", trainer, env, env_params)
        test = jax.jit(  # compiled once a suite, run once a seed
            lambda p, env=env, env_params=env_params, policy_of=policy_of: run_episodes(
                env,
                env_params,
                policy_of(p),
                jax.random.key(TEST_KEY),
                episodes,
                env_params.max_steps_in_episode,
            )
        )
        for row, p in zip(rows, params, strict=True):
            out = test(p)
            row["tests"][family.name] = outcome(out)
            if family.name == "held-out" and env.config.maze == "families":
                names = env.config.families
                layout = np.asarray(out["layout"]) % len(names)
                for i, name in enumerate(names):
                    row["tests"][f"held-out {name}"] = outcome(out, layout == i)
        print(f"  {family.name}: {[r['tests'][family.name]['success'] for r in rows]}", flush=True)
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    names = list(dict.fromkeys(name for r in rows for name in r["tests"]))
    head = "| row | seed | setting | train s | env steps | episodes | " + " | ".join(names) + " |"
    lines = [head, "|" + "---|" * (6 + len(names))]
    for r in sorted(rows, key=lambda r: (r["row"], label_suffix(r), r.get("seed", 0))):
        tests = r["tests"]
        train_s = "n/a" if r["train_s"] is None else f"{r['train_s']:.1f}"
        steps = "n/a" if r["env_steps"] is None else f"{r['env_steps']:,}"
        cells = [
            f"{tests[n]['success']:.3f} / {tests[n]['collision']:.3f}" if n in tests else "n/a"
            for n in names
        ]
        lines.append(
            f"| {r['row']} | {r.get('seed', 0)} | {r['label']}{label_suffix(r)} | {train_s} | "
            f"{steps} | {r['episodes']} | " + " | ".join(cells) + " |"
        )
    text = "\n".join(lines) + (
        "\n\nCells: greedy success / collision rate over a row's episodes per cell "
        f"(test key {TEST_KEY}, mazes round-robin; held-out: maze_seed {HELD_OUT_MAZE_SEED}, "
        f"1,000 mazes, families {', '.join(generators.FAMILIES)} in turn). Train s: of all the "
        "seeds trained together with it (vmapped).\n"
    )
    return text + over_seeds(rows)


def label_suffix(row: dict[str, Any]) -> str:
    """What a table adds to the label of a row tested from its exported npz or through the
    collision monitor."""
    tested = f", {row['tested']}" if row.get("tested") else ""
    return tested + (", shielded" if row.get("policy") == "shielded" else "")


def over_seeds(rows: list[dict[str, Any]]) -> str:
    """Mean and standard deviation of success over the seeds of each row (and policy) tested
    with more than one (the latest result of each seed)."""
    latest = {(r["row"], label_suffix(r), r.get("seed", 0)): r for r in rows}
    by_row: dict[str, list[dict[str, Any]]] = {}
    for (row, policy, _), r in sorted(latest.items()):
        by_row.setdefault(f"{row}{policy}", []).append(r)
    by_row = {row: rs for row, rs in by_row.items() if len(rs) > 1}
    if not by_row:
        return ""
    names = list(dict.fromkeys(n for rs in by_row.values() for r in rs for n in r["tests"]))
    lines = [
        "\n## Over seeds\n",
        "| row | seeds | " + " | ".join(names) + " |",
        "|" + "---|" * (2 + len(names)),
    ]
    for row, rs in by_row.items():
        cells = []
        for n in names:
            x = np.array([r["tests"][n]["success"] for r in rs if n in r["tests"]])
            cells.append(f"{x.mean():.3f} ± {x.std(ddof=1):.3f}" if len(x) > 1 else "n/a")
        seeds = ", ".join(str(r.get("seed", 0)) for r in rs)
        lines.append(f"| {row} | {seeds} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n\nCells: mean ± standard deviation of greedy success.\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.mapfree_sweep")
    p.add_argument("--rows", default=",".join(map(str, range(len(ROWS)))))
    p.add_argument("--episodes", type=int, default=2000)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/mapfree_sweep.jsonl"))
    p.add_argument("--policies", type=Path, help="folder to write each row's policy (rowN.npz)")
    p.add_argument("--trained", type=Path, help="test each row's rowN.npz from this folder")
    p.add_argument("--pretrained", help="test this shipped policy on each row's env")
    p.add_argument("--seeds", default="0", help="training seeds, vmapped together: 0,1,2")
    p.add_argument(
        "--shielded", action="store_true", help="test through the lidar collision monitor"
    )
    p.add_argument("--render", action="store_true", help="only rebuild the table from --out")
    args = p.parse_args(argv)
    if args.render:
        rows = [json.loads(line) for line in args.out.read_text().splitlines() if line]
        args.out.with_suffix(".md").write_text(markdown(rows))
        return 0
    try:
        indices = [int(i) for i in args.rows.split(",")]
        if any(not 0 <= i < len(ROWS) for i in indices):
            raise ValueError
    except ValueError:
        print(f"--rows {args.rows!r}: give indices in 0..{len(ROWS) - 1}", file=sys.stderr)
        return 2
    try:
        seeds = tuple(int(s) for s in args.seeds.split(","))
        if not seeds or min(seeds) < 0 or len(set(seeds)) < len(seeds):
            raise ValueError
    except ValueError:
        print(f"--seeds {args.seeds!r}: give distinct seeds >= 0, e.g. 0,1,2", file=sys.stderr)
        return 2
    trained = args.pretrained or args.trained
    for i in indices:  # a missing start fails now, not after the rows before it trained
        start = ROWS[i][3].get("init_from", "")
        if trained is None and start.endswith(".npz") and not Path(start).is_file():
            made_by = MADE_BY.get(start, "no command here writes it")
            print(f"row {i} starts from {start}, not there: {made_by}", file=sys.stderr)
            return 2
    if args.policies is not None and trained is None:
        try:  # before training, so that a bad folder costs no GPU time
            args.policies.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            print(f"--policies {args.policies}: {e.strerror or e}", file=sys.stderr)
            return 2
    machine = machine_info()
    rows = []
    for i in indices:
        print(f"row {i}: {ROWS[i][0]}", flush=True)
        results = run_row(i, args.episodes, args.policies, trained, seeds, args.shielded)
        results = [r | {"machine": machine} for r in results]
        rows += results
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with args.out.open("a") as f:
            f.writelines(json.dumps(r) + "\n" for r in results)
        if results[0]["train_s"] is not None:
            print(f"  {results[0]['env_steps']:,} steps a seed, {results[0]['train_s']} s")
    args.out.with_suffix(".md").write_text(markdown(rows))
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
