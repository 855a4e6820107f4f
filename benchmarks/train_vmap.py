"""One seed's whole training run compiled two ways, in one process: ``jit(train)`` on one key,
and ``jit(vmap(train))`` on a batch of one key (what the training CLI compiles for
``--num-seeds 1``). Same config, same key, same program apart from the batch axis; each
compiled once (compile time apart) and run in turn ``--repeats`` times, the best run kept.

    python -m benchmarks.train_vmap [--env RobotNav-v0] [--algo pqn] [--steps 20000000] \
        [--repeats 2] [--out benchmarks/results/train_vmap.json]

Also reports the largest difference between the two runs' success curves: the batch axis
should not change what is learned, though float sums may differ in the last bits.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from benchmarks.common import machine_info, write_results
from jaxnav.config import TrainConfig
from jaxnav.train import Trainer, jit_training


def measure(env: str, algo: str, steps: int, repeats: int) -> dict[str, Any]:
    config = TrainConfig.for_env(env, algo=algo, total_timesteps=steps, eval_episodes=0)
    trainer = Trainer(config)
    key = jax.random.key(0)
    programs = {
        "jit(train)": (jit_training(trainer.train), key),
        "jit(vmap(train))": (jit_training(jax.vmap(trainer.train)), key[None]),
    }
    rows: dict[str, dict[str, Any]] = {}
    compiled = {}
    for name, (fn, arg) in programs.items():
        t0 = time.perf_counter()
        compiled[name] = fn.lower(arg).compile()
        rows[name] = {"compile_s": time.perf_counter() - t0, "train_s": float("inf")}
    curves = {}
    for _ in range(repeats):  # in turn, so drifts in clock or load hit both alike
        for name, (_, arg) in programs.items():
            t0 = time.perf_counter()
            _, metrics = jax.block_until_ready(compiled[name](arg))
            rows[name]["train_s"] = min(rows[name]["train_s"], time.perf_counter() - t0)
            curves[name] = np.asarray(metrics["success_rate"]).reshape(-1)
            rows[name]["env_steps"] = int(np.asarray(metrics["env_steps"]).reshape(-1)[-1])
    for row in rows.values():
        row["env_steps_per_s"] = row["env_steps"] / row["train_s"]
    a, b = curves.values()
    return {
        "env": env,
        "algo": algo,
        "num_envs": config.num_envs,
        "rows": rows,
        "vmap_speedup": rows["jit(train)"]["train_s"] / rows["jit(vmap(train))"]["train_s"],
        "max_curve_difference": float(np.abs(a - b).max()),
    }


def markdown(result: dict[str, Any]) -> str:
    m = result["machine"]
    lines = [
        f"# One seed's training, jit(train) vs jit(vmap(train)): {result['env']}, "
        f"{result['algo']}, {result['num_envs']:,} envs",
        "",
        f"`{result['command']}`; {m['devices'][0]}, jax {m['jax_version']}; best of "
        f"{result['repeats']} runs each, in turn.",
        "",
        "| program | compile s | train s | env steps | env steps/s |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, r in result["rows"].items():
        lines.append(
            f"| {name} | {r['compile_s']:.1f} | {r['train_s']:.2f} | {r['env_steps']:,} | "
            f"{r['env_steps_per_s']:,.0f} |"
        )
    lines += [
        "",
        f"jit(vmap(train)) is {result['vmap_speedup']:.2f}x as fast; the success curves differ "
        f"by at most {result['max_curve_difference']:.4f}.",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.train_vmap")
    p.add_argument("--env", default="RobotNav-v0")
    p.add_argument("--algo", default="pqn")
    p.add_argument("--steps", type=int, default=20_000_000)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/train_vmap.json"))
    args = p.parse_args(argv)
    if args.steps < 1 or args.repeats < 1:
        p.exit(2, f"{p.prog}: --steps {args.steps} / --repeats {args.repeats}: must be >= 1\n")
    result = measure(args.env, args.algo, args.steps, args.repeats)
    result |= {
        "command": "python -m benchmarks.train_vmap " + " ".join(argv or sys.argv[1:]),
        "repeats": args.repeats,
        "machine": machine_info(),
    }
    text = markdown(result)
    write_results(args.out, result, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
