"""What memory costs in training time: the same PQN run with and without a GRU (``--memory``).

    python -m benchmarks.memory_cost [--memory 64] [--num-envs 256] [--iterations 40]

Each run trains ``iterations`` iterations of ``num_envs`` x 32 steps on ``RobotNav-v0``'s
map-free observation (one frame, 64 mazes), a 256-256 network in float32, 4 epochs of 8
minibatches; compile time apart, training time the best of two calls. The ratio is to the
feed-forward run (``memory`` 0) in the same process. Writes a markdown table and JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import jax

from benchmarks.common import machine_info
from jaxnav.config import TrainConfig
from jaxnav.envs.robot.env import MAPFREE_SENSORS
from jaxnav.train import Trainer, jit_training

ROLLOUT = 32


def measure(memory: int, num_envs: int, iterations: int) -> dict[str, Any]:
    steps = num_envs * ROLLOUT * iterations
    config = TrainConfig.for_env(
        "RobotNav-v0", algo="pqn", env_kwargs={**MAPFREE_SENSORS, "frames": 1, "num_layouts": 64},
        num_envs=num_envs, rollout_length=ROLLOUT, num_minibatches=8, num_epochs=4,
        hidden_sizes=(256, 256), compute_dtype="float32", fused_layer_norm=False,
        total_timesteps=steps, log_interval=steps // 2, eval_episodes=0, memory=memory,
    )  # fmt: skip
    trainer = Trainer(config)
    key = jax.random.key(0)
    t0 = time.perf_counter()
    train = jit_training(trainer.train).lower(key).compile()
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(2):
        t0 = time.perf_counter()
        jax.block_until_ready(train(key))
        times.append(time.perf_counter() - t0)
    best = min(times)
    return {
        "memory": memory,
        "env_steps": steps,
        "compile_s": round(compile_s, 1),
        "train_s": round(best, 2),
        "env_steps_per_s": round(steps / best),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.memory_cost")
    p.add_argument("--memory", type=int, default=64, help="the GRU's units")
    p.add_argument("--num-envs", type=int, default=256)
    p.add_argument("--iterations", type=int, default=40)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/memory_cost.json"))
    args = p.parse_args(argv)
    rows = [measure(m, args.num_envs, args.iterations) for m in (0, args.memory)]
    for r in rows:
        r["time_vs_feed_forward"] = round(r["train_s"] / rows[0]["train_s"], 2)
    result = {"machine": machine_info(), "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    lines = ["| memory | env steps | compile s | train s | env steps/s | time / feed-forward |",
             "|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for r in rows:
        lines.append(
            f"| {r['memory']} | {r['env_steps']:,} | {r['compile_s']} | {r['train_s']} | "
            f"{r['env_steps_per_s']:,} | {r['time_vs_feed_forward']} |"
        )
    table = "\n".join(lines) + "\n"
    args.out.with_suffix(".md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
