"""Scaling over devices: env and training throughput on 1..D devices in one run, as a ratio to
one device.

    python -m benchmarks.scaling [--devices 1,2] [--envs "GridMaze-v0,RobotSimple-v0 mjx"]
        [--envs-per-device 65536] [--train-envs-per-device 4096] [--train-env GridMaze-v0]
        [--steps 200] [--intervals 5] [--rounds 3] [--out benchmarks/results/scaling.json]

Weak scaling: each device gets the same work, so perfect scaling is a ratio equal to the device
count.

- ``env`` rows: ``benchmarks.env_throughput``'s random-action rollout of ``--envs-per-device``
  envs per device (``shard_map``; no communication but the final reward sum).
- ``train, envs split`` rows: one agent (one seed) whose ``--train-envs-per-device`` envs per
  device and batch (``--batch-per-device`` per device) are split over the devices, gradients
  averaged across them every update (``Trainer.sharded``, what ``--devices`` runs).
- ``train, a seed per device`` rows: one independent seed per device with the one-device config.

Train rows time ``--intervals`` compiled logging intervals (each ``--iterations`` iterations of
one vectorized env step and one gradient step, learning from the first iteration) after a
warm-up interval; steps/s counts env steps of all seeds. Rows of one kind are timed in turn,
round by round (median of ``--rounds``), so load changes hit them alike. Compile time is
reported apart. On CPU, try it with ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` (the
devices then share the cores, so expect no speed-up there: it checks the program, not the
hardware).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from benchmarks.common import machine_info, time_in_turn, write_results
from benchmarks.env_throughput import ALL_ENVS, prepare
from jaxnav import run_dir
from jaxnav.config import TrainConfig
from jaxnav.train import COMPILER_OPTIONS, Trainer

DEFAULT_OUT = Path("benchmarks/results/scaling.json")


def train_row(label: str, config: TrainConfig, intervals: int) -> dict[str, Any]:
    """Compile a training config's interval; ``run()`` times ``intervals`` of them."""
    trainer = Trainer(config)
    keys = run_dir.seed_keys(config)
    t0 = time.perf_counter()
    init, interval, state_like = trainer.sharded(keys)
    log_like = jax.ShapeDtypeStruct((), np.int32)
    init = init.lower(keys).compile(COMPILER_OPTIONS)
    interval = interval.lower(state_like, log_like).compile(COMPILER_OPTIONS)
    compile_s = time.perf_counter() - t0
    holder = {"state": init(keys), "log": 0}

    def run() -> float:
        t0 = time.perf_counter()
        for _ in range(intervals):
            holder["state"], metrics = interval(holder["state"], np.int32(holder["log"]))
            holder["log"] += 1
        jax.block_until_ready(metrics)
        return time.perf_counter() - t0

    run()  # warm-up
    return {
        "row": label,
        "devices": config.devices,
        "num_envs": config.num_envs * config.num_seeds,
        "steps": intervals * config.iterations_per_log,  # per env
        "compile_s": compile_s,
        "run": run,
    }


def train_config(args: argparse.Namespace, devices: int, split_envs: bool) -> TrainConfig:
    shards = devices if split_envs else 1
    num_envs = args.train_envs_per_device * shards
    return TrainConfig.for_env(
        args.train_env,
        num_envs=num_envs,
        num_seeds=1 if split_envs else devices,
        devices=devices,
        batch_size=args.batch_per_device * shards,
        # one gradient step of the batch an iteration, whatever the env count
        replay_ratio=args.batch_per_device / args.train_envs_per_device,
        buffer_size=num_envs * 64,
        learning_starts=num_envs * 3,  # n_step <= 3: learning from the first iteration
        log_interval=num_envs * args.iterations,
        total_timesteps=num_envs * args.iterations * (args.rounds + 1) * args.intervals,
        hidden_sizes=tuple(args.hidden_sizes),
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.scaling", description=__doc__)
    p.add_argument("--devices", default=None, help="device counts, e.g. 1,2 (default 1..all)")
    p.add_argument("--envs", default="GridMaze-v0,RobotSimple-v0 mjx,RobotSimple-v0 kinematic")
    p.add_argument("--envs-per-device", type=int, default=65536)
    p.add_argument("--steps", type=int, default=200, help="env steps per timed env rollout")
    p.add_argument("--train-env", default="GridMaze-v0")
    p.add_argument("--train-envs-per-device", type=int, default=4096)
    p.add_argument("--batch-per-device", type=int, default=128)
    p.add_argument("--hidden-sizes", default="512,256,128,64")
    p.add_argument("--iterations", type=int, default=50, help="iterations per interval")
    p.add_argument("--intervals", type=int, default=5, help="intervals per timed train run")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--sections", default="env,train")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = p.parse_args(argv)
    args.hidden_sizes = [int(w) for w in args.hidden_sizes.split(",")]
    counts = (
        list(range(1, jax.device_count() + 1))
        if args.devices is None
        else [int(d) for d in args.devices.split(",")]
    )
    if not counts or min(counts) < 1 or max(counts) > jax.device_count():
        p.error(f"--devices {args.devices}: this machine has {jax.device_count()} device(s)")
    envs = [e.strip() for e in args.envs.split(",") if e.strip()]
    if unknown := [e for e in envs if e not in ALL_ENVS]:
        p.error(f"--envs: unknown {', '.join(unknown)} (known: {', '.join(ALL_ENVS)})")
    sections = set(args.sections.split(","))

    groups: list[list[dict[str, Any]]] = []
    if "env" in sections:
        for env in envs:
            group = []
            for d in counts:
                row = prepare(env, args.envs_per_device * d, args.steps, devices=d)
                row |= {"row": f"env {env}", "devices": d}
                group.append(row)
                print(f"compiled {row['row']} on {d} device(s) in {row['compile_s']:.1f}s")
            groups.append(group)
    if "train" in sections:
        for split_envs, label in ((True, "envs split"), (False, "a seed per device")):
            group = []
            for d in counts:
                config = train_config(args, d, split_envs)
                group.append(train_row(f"train {args.train_env}, {label}", config, args.intervals))
                print(f"compiled {group[-1]['row']} on {d} device(s)")
            groups.append(group)

    rows = []
    for group in groups:
        time_in_turn(group, args.rounds)
        base = None
        for row in group:
            row["steps_per_s"] = row["num_envs"] * row["steps"] / statistics.median(row["run_s"])
            base = base or row["steps_per_s"]
            row["ratio_vs_1"] = row["steps_per_s"] / base
            rows.append(row)

    header = "| row | devices | envs (all) | steps/s | ratio vs first | compile s |"
    lines = [header, "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['row']} | {r['devices']} | {r['num_envs']:,} | {r['steps_per_s']:.3g} | "
            f"{r['ratio_vs_1']:.2f}x | {r['compile_s']:.1f} |"
        )
    machine = machine_info()
    command = " ".join(sys.argv[1:] if argv is None else argv)
    markdown = "\n".join(
        [
            f"Scaling over devices ({jax.devices()[0].device_kind}, "
            f"{jax.device_count()} device(s)); ratio = steps/s over the first device count's.",
            "",
            *lines,
            "",
            f"Command: python -m benchmarks.scaling {command}",
        ]
    )
    print(markdown)
    write_results(args.out, {"machine": machine, "args": vars(args) | {"out": str(args.out)},
                             "rows": rows}, markdown)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
