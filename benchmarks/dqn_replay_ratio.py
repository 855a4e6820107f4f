"""The DQN's replay ratio across env counts, measured through the training command a user runs.

    python -m benchmarks.dqn_replay_ratio [--num-envs 16,64,256,1024] [--seeds 2]
        [--variants ratio,one-update] [--batch-sizes 128] [--out FILE.json]

(this CPU's rows: ``--out benchmarks/results/dqn_replay_ratio_cpu.json``)

Each row is ``python -m jaxnav.train --env GridMaze-v0`` (the paper's grid DQN: TrainConfig's
defaults) with ``--num-envs N --num-seeds S`` and nothing else changed but the run length:
``--total-timesteps 245760 --log-interval 16384``, because the default 240,000 env steps are no
whole number of iterations at 256 or 1024 envs (245,760 = 15 intervals of 16,384 at every
count here). Variants:

- ``ratio``: the default ``--replay-ratio 8`` (8 sampled transitions per env step), so
  ``8 * N / B`` gradient steps of batch B per iteration: the same sampled transitions per env
  step at every N. A row per B of ``--batch-sizes`` (default: the default batch, 128) where
  that count is whole, so larger batches (fewer, larger gradient steps, what a GPU runs
  faster) are measured at the same replay ratio;
- ``one-update``: ``--replay-ratio 128/N``, one gradient step per iteration, what the defaults
  gave before ``replay_ratio`` replaced ``updates_per_iteration`` (left out at N = 16, where
  it is the ``ratio`` row).

Success is the training command's own greedy evaluation (``summary.json``: 1000 episodes per
seed); train s is its training time (compile excluded). The runs go one after another; the
1-minute load average before each is recorded (other processes slow a run down). Writes the
JSON after every row and a markdown table beside it (``.md``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import machine_info, write_results
from jaxnav.config import TrainConfig
from jaxnav.run_dir import config_from_json

ENV = "GridMaze-v0"
BATCH = TrainConfig.batch_size  # the default every run keeps
RUN = ["--total-timesteps", "245760", "--log-interval", "16384"]
VARIANTS = ("ratio", "one-update")


def replay_ratio(variant: str, num_envs: int) -> float:
    return 8.0 if variant == "ratio" else BATCH / num_envs


def measure(
    variant: str, num_envs: int, seeds: int, tmp: Path, batch_size: int = BATCH
) -> dict[str, Any]:
    """Train ``seeds`` seeds with the CLI; the row of the results."""
    ratio = replay_ratio(variant, num_envs)
    out = tmp / f"{variant}-{num_envs}-{batch_size}"
    argv = ["--env", ENV, "--num-envs", str(num_envs), "--num-seeds", str(seeds), *RUN]
    argv += ["--replay-ratio", repr(ratio)]
    if batch_size != BATCH:
        argv += ["--batch-size", str(batch_size)]
    cmd = [sys.executable, "-m", "jaxnav.train", *argv, "--out", str(out), "--quiet"]
    print("$", " ".join(cmd), flush=True)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall_s = time.perf_counter() - t0
    if done.returncode:
        sys.exit(f"jaxnav.train failed ({done.returncode}):\n{done.stdout}\n{done.stderr}")
    summary = json.loads((out / "summary.json").read_text())
    saved = json.loads((out / "config.json").read_text())["config"]
    config = config_from_json(saved)
    learning_iterations = config.iterations - config.first_learning_iteration
    return {
        "variant": variant,
        "num_envs": num_envs,
        "batch_size": config.batch_size,
        "replay_ratio": config.replay_ratio,
        "updates_per_iteration": config.updates_per_iteration,
        "gradient_steps_per_seed": config.updates_per_iteration * learning_iterations,
        "flags": argv,
        "success_mean": summary["trained"]["success_rate"],
        "success_per_seed": [s["success_rate"] for s in summary["trained_per_seed"]],
        "episodes_per_seed": summary["trained_per_seed"][0]["episodes"],
        "train_s": summary["train_s"],
        "compile_s": summary["compile_s"],
        "command_wall_s": wall_s,
        "loadavg_1m_before": load,
        "config": saved,
    }


def steps_per_s(result: dict[str, Any], row: dict[str, Any]) -> str:
    """Env steps per second of training, all seeds together."""
    steps = int(RUN[1]) * result["seeds"]
    return f"{steps / row['train_s']:,.0f}" if row["train_s"] > 0 else "n/a"


def markdown(result: dict[str, Any]) -> str:
    m = result["machine"]
    lines = [
        "# DQN replay ratio across env counts (benchmarks/dqn_replay_ratio.py)\n",
        f"`{result['command']}`: each row is",
        f"`python -m jaxnav.train --env {ENV} --num-envs N --num-seeds {result['seeds']} "
        f"{' '.join(RUN)} --replay-ratio R [--batch-size B]`; greedy success of the "
        "command's own evaluation (summary.json, 1000 episodes per seed), mean over seeds "
        "with each seed in brackets; train s: the command's training time for all seeds "
        "together (vmapped), compile excluded; env steps/s: all seeds' env steps over train "
        "s. Variants: `ratio`, the default replay ratio 8 (8 * N / B gradient steps of batch "
        "B per iteration); `one-update`, replay ratio 128 / N, one gradient step per "
        "iteration, what the defaults gave before replay_ratio replaced updates_per_iteration "
        "(at N = 16 it is the ratio row).\n",
        f"Machine: {m['platform']}, {m['cpu_count']} CPU cores, {m['devices'][0]} "
        f"({m['backend']}), jax {m['jax_version']}, shared with other jobs (1-minute load "
        f"average before each run in the last column); {m['date'][:10]}.\n",
        "| variant | num_envs | replay ratio | batch | gradient steps / iteration | gradient "
        "steps per seed | greedy success (per seed) | train s | env steps/s | compile s "
        "| load avg |",
        "|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|",
    ]
    for r in result["rows"]:
        seeds = ", ".join(f"{s:.3f}" for s in r["success_per_seed"])
        lines.append(
            f"| {r['variant']} | {r['num_envs']} | {r['replay_ratio']:g} | "
            f"{r['batch_size']} | {r['updates_per_iteration']} | "
            f"{r['gradient_steps_per_seed']:,} | {r['success_mean']:.3f} ({seeds}) | "
            f"{r['train_s']:.1f} | {steps_per_s(result, r)} | {r['compile_s']:.1f} | "
            f"{r['loadavg_1m_before']:.1f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--num-envs", default="16,64,256,1024", help="comma-separated env counts")
    ap.add_argument("--seeds", type=int, default=2, help="--num-seeds of every run")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"of {', '.join(VARIANTS)}")
    ap.add_argument("--batch-sizes", default=str(BATCH), help="comma-separated, ratio rows")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/dqn_replay_ratio.json"))
    args = ap.parse_args(argv)
    counts = [int(n) for n in args.num_envs.split(",")]
    batches = [int(b) for b in args.batch_sizes.split(",")]
    variants = [v for v in args.variants.split(",") if v]
    if any(v not in VARIANTS for v in variants) or any(245_760 % n for n in counts):
        ap.error(f"variants of {VARIANTS}; env counts dividing 245760")
    given = sys.argv[1:] if argv is None else argv
    command = " ".join(["python -m benchmarks.dqn_replay_ratio", *given])
    result: dict[str, Any] = {"machine": machine_info(), "command": command, "seeds": args.seeds}
    result["rows"] = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in counts:
            for v in variants:
                if v == "one-update" and replay_ratio(v, n) == replay_ratio("ratio", n):
                    continue  # the same run as the ratio row
                for b in batches if v == "ratio" else [BATCH]:
                    if (replay_ratio(v, n) * n) % b:
                        continue  # not a whole number of gradient steps per iteration
                    result["rows"].append(measure(v, n, args.seeds, Path(tmp), b))
                    print(markdown(result).splitlines()[-1], flush=True)
                    write_results(args.out, result, markdown(result))
    print(markdown(result))
    return result


if __name__ == "__main__":
    main()
