"""Train several configs (each over several seeds, vmapped) and evaluate them greedily.

Used to choose GridMaze-v0's default observation and the default hyperparameters by
measurement. Example (the observation-mode table of docs/paper.md):

    python -m benchmarks.grid_sweep --seeds 3 \
        --variant onehot '{"env_kwargs": {"obs_mode": "onehot"}}' \
        --variant paper '{"env_kwargs": {"obs_mode": "paper"}}'

Each variant is a JSON dict of TrainConfig overrides. Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

from benchmarks.common import machine_info, write_results
from jaxnav.config import TrainConfig
from jaxnav.evaluate import evaluate_seeds, format_value, mean_of
from jaxnav.train import Trainer, jit_training


def run_variant(overrides: dict, seeds: int, eval_episodes: int, base: dict) -> dict:
    cfg = TrainConfig(**{**base, **overrides, "num_seeds": seeds})
    if "hidden_sizes" in overrides:
        cfg = dataclasses.replace(cfg, hidden_sizes=tuple(overrides["hidden_sizes"]))
    trainer = Trainer(cfg)
    keys = jax.random.split(jax.random.key(cfg.seed), seeds)
    t0 = time.perf_counter()
    train = jit_training(jax.vmap(trainer.train)).lower(keys).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    ts, metrics = jax.block_until_ready(train(keys))
    train_s = time.perf_counter() - t0

    per_seed = evaluate_seeds(trainer, ts.params, eval_episodes, seed=12345)
    curve = np.asarray(metrics["success_rate"]).mean(axis=0).round(3).tolist()
    env_steps = int(np.asarray(metrics["env_steps"])[:, -1].sum())  # all seeds
    return {
        "overrides": overrides,
        "compile_s": compile_s,
        "train_s": train_s,
        "env_steps": env_steps,
        "env_steps_per_s": env_steps / train_s,
        "per_seed": per_seed,
        "success_mean": float(np.mean([s["success_rate"] for s in per_seed])),
        "success_min": float(np.min([s["success_rate"] for s in per_seed])),
        # None (n/a) where no seed had a successful episode to measure it on
        "path_ratio_mean": mean_of(per_seed)["mean_path_ratio"],
        "train_success_curve": curve,
    }


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", nargs=2, action="append", metavar=("NAME", "JSON"), default=[])
    ap.add_argument("--base", default="{}", help="JSON overrides shared by all variants")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--eval-episodes", type=int, default=1000)
    ap.add_argument("--out", default="benchmarks/results/grid_sweep.json")
    args = ap.parse_args(argv)
    base = json.loads(args.base)
    rows = []
    lines = [
        "| variant | success mean | success min | path ratio | compile s | train s "
        "| env steps/s (all seeds) |",
        "|---|---|---|---|---|---|---|",
    ]
    print("\n".join(lines), flush=True)
    for name, spec in args.variant:
        r = run_variant(json.loads(spec), args.seeds, args.eval_episodes, base)
        r["name"] = name
        rows.append(r)
        lines.append(
            f"| {name} | {r['success_mean']:.3f} | {r['success_min']:.3f} | "
            f"{format_value(r['path_ratio_mean'])} | {r['compile_s']:.1f} | {r['train_s']:.1f} | "
            f"{r['env_steps_per_s']:,.0f} |"
        )
        print(lines[-1], flush=True)
    meta = {"machine": machine_info(), "base": base, "seeds": args.seeds}
    write_results(Path(args.out), {"meta": meta, "rows": rows}, "\n".join(lines))
    return rows


if __name__ == "__main__":
    main()
