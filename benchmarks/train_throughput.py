"""Training throughput: gradient steps/s of the bare update vs. inside the full training loop.

    python -m benchmarks.train_throughput [--batch-sizes 128] [--num-envs 16] [--iterations N]
        [--hidden-sizes 512,256,128,64] [--updates-per-iteration 1] [--buffer-size 100000]
        [--seed 0] [--out benchmarks/results/train_throughput.json]

Every row is the default ``TrainConfig`` (GridMaze-v0, the paper's 512-256-128-64 dueling
double DQN, Adam, n_step 1, a 100k-transition buffer) with the given batch size, and:

- ``learning_starts = num_envs * n_step`` and ``log_interval = iterations * num_envs``, so one
  compiled ``Trainer.run(ts, first_log, 1)`` is ``--iterations`` iterations, all of them past
  ``learning_starts`` (gradient steps really run in every iteration);
- a replay buffer filled before any timing with ``buffer_rows`` vectorized steps of real
  GridMaze transitions under uniformly random actions (what an eps = 1 warm-up writes), so
  sampling reads a full-size buffer as in the second half of a real run.

Measured per row, each compiled once (``jit(f).lower(...).compile()``, reported as compile s)
and then timed 3 times (median reported). State arguments are donated and each timed run
continues from the previous one's state, as consecutive chunks of a training run would. The
timed runs of the three measurements are interleaved (bare, loop, no-update loop, bare, ...)
so background load on a shared machine hits all three alike.

- ``bare``: ``jax.lax.scan`` of ``Trainer._update`` (sample a batch, loss, grad, Adam step)
  over ``iterations * updates_per_iteration`` steps -> updates/s.
- ``loop``: ``Trainer.run`` (acting, vectorized env step with auto-reset, buffer write,
  gradient steps, target-network update, metrics) -> iterations/s, updates/s, env steps/s.
- ``no-update loop``: the same loop with ``learning_starts`` never reached (the ``cond``
  skips the gradient steps): what the loop costs besides the updates.

``ratio`` = loop updates/s / bare updates/s of the medians (goal: >= 0.85 at the default
setting). The JSON also has ``ratio_best_runs`` (fastest bare run / fastest loop run) and the
process CPU seconds of every timed run (``cpu_s``), to judge runs on a loaded machine.
``replay ratio`` = batch_size * updates_per_iteration / num_envs: sampled transitions per
env step. ``predicted ratio`` = the ratio if the loop cost exactly bare update time plus
no-update loop time (a gap between the two is interaction cost, e.g. buffer copies).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from benchmarks.common import machine_info, write_results
from jaxnav.agents import dqn
from jaxnav.config import MAX_STEPS, TrainConfig
from jaxnav.train import Trainer, TrainState

DEFAULT_OUT = Path("benchmarks/results/train_throughput.json")
GOAL_RATIO = 0.85
NEVER = MAX_STEPS // 2  # learning_starts of the no-update loop (env steps are int32)


def make_config(
    batch_size: int,
    num_envs: int,
    iterations: int,
    hidden_sizes: tuple[int, ...],
    updates_per_iteration: int,
    buffer_size: int,
    learning: bool = True,
) -> TrainConfig:
    base = TrainConfig()
    starts = {"learning_starts": num_envs * base.n_step}
    if not learning:
        starts = {"learning_starts": NEVER, "total_timesteps": NEVER + 1}
    return dataclasses.replace(
        base,
        batch_size=batch_size,
        num_envs=num_envs,
        hidden_sizes=hidden_sizes,
        updates_per_iteration=updates_per_iteration,
        buffer_size=buffer_size,
        log_interval=iterations * num_envs,
        **starts,
    )


def filled_state(trainer: Trainer, key: jax.Array) -> TrainState:
    """``trainer.init`` then ``buffer_rows`` rows of random-action GridMaze transitions.

    One jitted function (an eager ``Trainer.init`` alone takes seconds of op dispatch).
    """
    env, params, n = trainer.env, trainer.env_params, trainer.config.num_envs
    vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def body(carry: tuple, key: jax.Array) -> tuple[tuple, None]:
        buf, env_state, obs = carry
        k_act, k_step = jax.random.split(key)
        action = jax.random.randint(k_act, (n,), 0, env.num_actions)
        next_obs, env_state, reward, terminated, truncated, info = vstep(
            jax.random.split(k_step, n), env_state, action, params
        )
        done = terminated | truncated
        buf = dqn.buffer_add(buf, obs, action, reward, info["final_observation"], terminated, done)
        return (buf, env_state, next_obs), None

    @jax.jit
    def fill(key: jax.Array) -> TrainState:
        k_init, k_fill = jax.random.split(key)
        ts = trainer.init(k_init)
        rows = ts.buffer.capacity
        init = (ts.buffer, ts.env_state, ts.obs)
        (buf, env_state, obs), _ = jax.lax.scan(body, init, jax.random.split(k_fill, rows))
        return ts.replace(buffer=buf, env_state=env_state, obs=obs)

    return jax.block_until_ready(fill(key))


def _copy(tree: Any) -> Any:
    return jax.tree.map(jnp.copy, tree)


def compile_donating(
    fn: Callable[[TrainState, jax.Array], tuple[TrainState, Any]],
    ts: TrainState,
    arg: jax.Array,
) -> tuple[Callable[[TrainState, jax.Array], tuple[TrainState, Any]], float]:
    """``jit(fn, donate_argnums=0)`` lowered and compiled; returns it and the seconds taken."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn, donate_argnums=0).lower(ts, arg).compile()
    return compiled, time.perf_counter() - t0


def time_interleaved(
    runs: dict[str, tuple[Callable, list[jax.Array]]], ts: TrainState
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Wall and process CPU seconds of one call per element of each run's args, round-robin.

    Each run gets its own copy of ``ts`` and chains its calls (the state is donated).
    Interleaving exposes every measurement to the same background load over time, so
    ratios between them stay meaningful on a shared machine.
    """
    states = {name: _copy(ts) for name in runs}
    wall: dict[str, list[float]] = {name: [] for name in runs}
    cpu: dict[str, list[float]] = {name: [] for name in runs}
    for r in range(max(len(args) for _, args in runs.values())):
        for name, (compiled, args) in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            states[name], _ = jax.block_until_ready(compiled(states[name], args[r]))
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    return wall, cpu


def measure(
    batch_size: int,
    num_envs: int,
    iterations: int,
    hidden_sizes: tuple[int, ...],
    updates_per_iteration: int,
    buffer_size: int,
    seed: int = 0,
) -> dict[str, Any]:
    """Fill a buffer, then compile and time bare updates, the loop and the no-update loop."""
    sizes = (batch_size, num_envs, iterations, hidden_sizes, updates_per_iteration, buffer_size)
    trainer = Trainer(make_config(*sizes))
    idle = Trainer(make_config(*sizes, learning=False))
    k_state, k_bare = jax.random.split(jax.random.key(seed))
    t0 = time.perf_counter()
    ts = filled_state(trainer, k_state)
    fill_s = time.perf_counter() - t0
    assert int(ts.buffer.size) == ts.buffer.capacity
    num_updates = iterations * updates_per_iteration

    def bare(ts: TrainState, key: jax.Array) -> tuple[TrainState, Any]:
        return jax.lax.scan(trainer._update, ts, jax.random.split(key, num_updates))

    def loop(tr: Trainer) -> Callable[[TrainState, jax.Array], tuple[TrainState, Any]]:
        return lambda ts, first_log: tr.run(ts, first_log, 1)

    # log index 1, 2, 3: iterations >= iterations_per_log >= learning_starts / num_envs
    logs = [jnp.asarray(i, jnp.int32) for i in (1, 2, 3)]
    keys = list(jax.random.split(k_bare, 3))
    bare_f, bare_c = compile_donating(bare, ts, keys[0])
    loop_f, loop_c = compile_donating(loop(trainer), ts, logs[0])
    idle_f, idle_c = compile_donating(loop(idle), ts, logs[0])
    times, cpu = time_interleaved(
        {"bare": (bare_f, keys), "loop": (loop_f, logs), "idle": (idle_f, logs)}, ts
    )
    bare_s, loop_s, idle_s = times["bare"], times["loop"], times["idle"]
    bare_t, loop_t, idle_t = (statistics.median(s) for s in (bare_s, loop_s, idle_s))
    bare_ups = num_updates / bare_t
    loop_ips = iterations / loop_t
    return {
        "batch_size": batch_size,
        "num_envs": num_envs,
        "updates_per_iteration": updates_per_iteration,
        "hidden_sizes": list(hidden_sizes),
        "iterations": iterations,
        "buffer_rows": ts.buffer.capacity,
        "replay_ratio": batch_size * updates_per_iteration / num_envs,
        "fill_s": fill_s,
        "bare": {
            "compile_s": bare_c,
            "run_s": bare_s,
            "cpu_s": cpu["bare"],
            "updates": num_updates,
            "updates_per_s": bare_ups,
        },
        "loop": {
            "compile_s": loop_c,
            "run_s": loop_s,
            "cpu_s": cpu["loop"],
            "iterations_per_s": loop_ips,
            "updates_per_s": loop_ips * updates_per_iteration,
            "env_steps_per_s": loop_ips * num_envs,
        },
        "no_update_loop": {
            "compile_s": idle_c,
            "run_s": idle_s,
            "cpu_s": cpu["idle"],
            "iterations_per_s": iterations / idle_t,
            "env_steps_per_s": iterations * num_envs / idle_t,
        },
        "ratio": loop_ips * updates_per_iteration / bare_ups,
        "ratio_best_runs": min(bare_s) / min(loop_s),
        "predicted_ratio": bare_t / (bare_t + idle_t),
        "meets_goal": loop_ips * updates_per_iteration / bare_ups >= GOAL_RATIO,
    }


def table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| batch | num_envs | replay ratio | compile s (bare / loop) | bare updates/s "
        "| loop updates/s (= it/s) | loop env steps/s | no-update loop it/s | ratio "
        "| predicted ratio |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        b, lp, idle = r["bare"], r["loop"], r["no_update_loop"]
        lines.append(
            f"| {r['batch_size']} | {r['num_envs']} | {r['replay_ratio']:g} | "
            f"{b['compile_s']:.1f} / {lp['compile_s']:.1f} | {b['updates_per_s']:,.0f} | "
            f"{lp['updates_per_s']:,.0f} | {lp['env_steps_per_s']:,.0f} | "
            f"{idle['iterations_per_s']:,.0f} | {r['ratio']:.2f} | {r['predicted_ratio']:.2f} |"
        )
    return "\n".join(lines)


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = TrainConfig()
    p.add_argument("--batch-sizes", default=str(default.batch_size), help="comma-separated")
    p.add_argument("--num-envs", type=int, default=default.num_envs)
    p.add_argument(
        "--iterations", type=int, default=1000, help="iterations (and updates) per timed run"
    )
    p.add_argument(
        "--hidden-sizes",
        default=",".join(map(str, default.hidden_sizes)),
        help="comma-separated MLP widths",
    )
    p.add_argument("--updates-per-iteration", type=int, default=default.updates_per_iteration)
    p.add_argument("--buffer-size", type=int, default=default.buffer_size, help="transitions")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output path")
    args = p.parse_args(argv)
    args.batch_sizes = _ints(args.batch_sizes)
    args.hidden_sizes = tuple(_ints(args.hidden_sizes))
    if (
        not args.batch_sizes
        or min(args.batch_sizes) < 1
        or args.num_envs < 1
        or args.iterations < 1
        or args.updates_per_iteration < 1
        or args.buffer_size < max(args.batch_sizes, default=1)
        or not args.hidden_sizes
        or min(args.hidden_sizes) < 1
    ):
        p.error(
            "batch sizes, num_envs, iterations and hidden sizes must be >= 1, "
            "buffer size >= every batch size"
        )
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the table, write the JSON (and a .md table next to it)."""
    args = parse_args(argv)
    info = machine_info()
    info.pop("gymnax_version", None)
    rows = []
    for b in args.batch_sizes:
        row = measure(
            b,
            args.num_envs,
            args.iterations,
            args.hidden_sizes,
            args.updates_per_iteration,
            args.buffer_size,
            args.seed,
        )
        print(
            f"batch {b:5d}: bare {row['bare']['updates_per_s']:9,.0f} updates/s, "
            f"loop {row['loop']['updates_per_s']:9,.0f} updates/s, ratio {row['ratio']:.2f}",
            file=sys.stderr,
        )
        rows.append(row)
    info["loadavg_1m_at_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    md = table(rows)
    print(md)
    config = dataclasses.asdict(
        make_config(
            args.batch_sizes[0],
            args.num_envs,
            args.iterations,
            args.hidden_sizes,
            args.updates_per_iteration,
            args.buffer_size,
        )
    )
    result = {
        "machine": info,
        "config": config | {"batch_size": args.batch_sizes},
        "iterations": args.iterations,
        "goal_ratio": GOAL_RATIO,
        "results": rows,
    }
    write_results(args.out, result, md)
    return result


if __name__ == "__main__":
    main()
