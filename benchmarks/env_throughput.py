"""Environment throughput: env steps/s of ``jax.lax.scan`` over ``vmap(env.step)``.

    python -m benchmarks.env_throughput [--num-envs 1,16,256,4096,16384] [--steps N]
        [--out benchmarks/results/env_throughput.json] [--envs NAME,NAME,...]

Each (env, num_envs) row jits one function that scans ``--steps`` steps of the vmapped step
with uniformly random actions (per-step action and key sampling included in the timing).
The scan carries the observation and sums the reward, so XLA cannot drop the observation
computation. "compile s" is trace + lower + XLA compile (``jit(f).lower(...).compile()``);
steps/s uses the median of ``--rounds`` runs after a warm-up; the rows of one num_envs are
timed in turn, round by round, so load changes hit them alike and ratios stay meaningful.

Rows: ``GridMaze-v0``, ``GridMaze-Random-v0`` (auto-reset ``env.step``), ``GridMaze-v0
step_env only`` (no time limit, no auto-reset: the cost of auto-reset is its ratio to
GridMaze-v0) and, when ``import gymnax`` works, gymnax's ``FourRooms-misc`` and
``MetaMaze-misc`` through gymnax's own ``make`` and auto-resetting ``step`` (5-tuple).
The ratio column compares with gymnax FourRooms-misc at the same num_envs when it was
measured in the same run, otherwise with GridMaze-v0.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

import jaxnav
from benchmarks.common import compile_timed, machine_info, time_in_turn, write_results

# (key, state, action) -> (obs, state, reward); one environment, vmapped by the benchmark
StepFn = Callable[[jax.Array, Any, jax.Array], tuple[jax.Array, Any, jax.Array]]
ResetFn = Callable[[jax.Array], tuple[jax.Array, Any]]

STEP_ENV_ONLY = "GridMaze-v0 step_env only"
OUR_ENVS = ("GridMaze-v0", "GridMaze-Random-v0", STEP_ENV_ONLY)
GYMNAX_ENVS = ("FourRooms-misc", "MetaMaze-misc")
ALL_ENVS = OUR_ENVS + GYMNAX_ENVS
DEFAULT_OUT = Path("benchmarks/results/env_throughput.json")


def build(name: str) -> tuple[ResetFn, StepFn, int]:
    """``(reset, step, num_actions)`` for one row name; gymnax rows import gymnax here."""
    if name in GYMNAX_ENVS:
        import gymnax  # bench extra; may be absent

        genv, gparams = gymnax.make(name)

        def gstep(key: jax.Array, state: Any, action: jax.Array) -> Any:
            obs, state, reward, _done, _info = genv.step(key, state, action, gparams)
            return obs, state, reward

        return (lambda k: genv.reset(k, gparams)), gstep, genv.num_actions
    env, params = jaxnav.make("GridMaze-v0" if name == STEP_ENV_ONLY else name)
    if name == STEP_ENV_ONLY:

        def step(key: jax.Array, state: Any, action: jax.Array) -> Any:
            obs, state, reward, _terminated, _info = env.step_env(key, state, action, params)
            return obs, state, reward
    else:

        def step(key: jax.Array, state: Any, action: jax.Array) -> Any:
            obs, state, reward, _terminated, _truncated, _info = env.step(
                key, state, action, params
            )
            return obs, state, reward

    return (lambda k: env.reset(k, params)), step, env.num_actions


def prepare(name: str, num_envs: int, steps: int, seed: int = 0) -> dict[str, Any]:
    """Compile one row's rollout; returns a record with ``run()`` that times one execution."""
    reset, step, num_actions = build(name)
    vstep = jax.vmap(step)

    def rollout(key: jax.Array, obs: jax.Array, state: Any) -> tuple[jax.Array, Any, jax.Array]:
        def body(carry: Any, key: jax.Array) -> tuple[Any, None]:
            obs, state, total = carry
            k_act, k_step = jax.random.split(key)
            # one 32-bit word per action: randint draws two, doubling the harness cost
            actions = (jax.random.bits(k_act, (num_envs,)) % num_actions).astype(jnp.int32)
            obs, state, reward = vstep(jax.random.split(k_step, num_envs), state, actions)
            return (obs, state, total + reward.astype(jnp.float32).sum()), None

        init = (obs, state, jnp.zeros((), jnp.float32))
        return jax.lax.scan(body, init, jax.random.split(key, steps))[0]

    k_reset, k_run = jax.random.split(jax.random.key(seed))
    obs, state = jax.block_until_ready(
        jax.jit(jax.vmap(reset))(jax.random.split(k_reset, num_envs))
    )
    run, compile_s = compile_timed(rollout, k_run, obs, state)
    return {"env": name, "num_envs": num_envs, "steps": steps, "compile_s": compile_s, "run": run}


def measure_interleaved(names: list[str], num_envs: int, steps: int, rounds: int) -> list[dict]:
    """Time every row ``rounds`` times in turn (row A, B, C, A, B, C, ...), so that a change of
    machine load hits all rows alike and the ratios stay meaningful; median per row."""
    rows = [prepare(name, num_envs, steps) for name in names]
    time_in_turn(rows, rounds)
    for row in rows:
        row["steps_per_s"] = num_envs * steps / statistics.median(row["run_s"])
    return rows


def add_ratios(rows: list[dict[str, Any]]) -> None:
    """Set ``baseline`` and ``ratio`` (steps/s over the baseline's) on every row."""
    by_key = {(r["env"], r["num_envs"]): r for r in rows}
    for r in rows:
        base = next(
            (
                by_key[(b, r["num_envs"])]
                for b in ("FourRooms-misc", "GridMaze-v0")
                if (b, r["num_envs"]) in by_key
            ),
            None,
        )
        r["baseline"] = None if base is None else base["env"]
        r["ratio"] = None if base is None else r["steps_per_s"] / base["steps_per_s"]


def autoreset_cost(rows: list[dict[str, Any]]) -> dict[int, float]:
    """num_envs -> steps/s of step_env only over GridMaze-v0's (how much auto-reset costs)."""
    sps = {(r["env"], r["num_envs"]): r["steps_per_s"] for r in rows}
    return {
        n: sps[(STEP_ENV_ONLY, n)] / sps[("GridMaze-v0", n)]
        for (e, n) in sps
        if e == STEP_ENV_ONLY and ("GridMaze-v0", n) in sps
    }


def table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| env | num_envs | compile s | steps/s | ratio | baseline |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.2f}"
        lines.append(
            f"| {r['env']} | {r['num_envs']} | {r['compile_s']:.2f} | "
            f"{r['steps_per_s']:,.0f} | {ratio} | {r['baseline'] or '-'} |"
        )
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--num-envs", default="1,16,256,4096,16384", help="comma-separated")
    p.add_argument("--steps", type=int, default=200, help="scan length per row")
    p.add_argument("--rounds", type=int, default=5, help="interleaved timed runs per row")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output path")
    p.add_argument("--envs", default=",".join(ALL_ENVS), help=f"comma-separated of {ALL_ENVS}")
    args = p.parse_args(argv)
    args.num_envs = [int(n) for n in args.num_envs.split(",")]
    args.envs = [e.strip() for e in args.envs.split(",") if e.strip()]
    unknown = [e for e in args.envs if e not in ALL_ENVS]
    if unknown or args.steps < 1 or args.rounds < 1 or min(args.num_envs) < 1:
        p.error(f"unknown envs {unknown} (valid: {ALL_ENVS}), or steps/num_envs < 1")
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the table, write the JSON (and a .md table next to it)."""
    args = parse_args(argv)
    info = machine_info()
    envs, skipped = list(args.envs), {}
    gymnax_wanted = [e for e in envs if e in GYMNAX_ENVS]
    if gymnax_wanted:
        try:
            import gymnax  # noqa: F401
        except ImportError as e:
            print(f"note: gymnax not importable ({e}); skipping {', '.join(gymnax_wanted)}")
            skipped = {g: f"import gymnax failed: {e}" for g in gymnax_wanted}
            envs = [e for e in envs if e not in GYMNAX_ENVS]
    for name in [e for e in envs if e in GYMNAX_ENVS]:
        try:  # a gymnax that imports but breaks on this jax
            prepare(name, 1, 2)
        except Exception as e:
            print(f"note: {name} failed ({type(e).__name__}: {e}); skipping it")
            skipped[name] = f"{type(e).__name__}: {e}"
    envs = [e for e in envs if e not in skipped]
    rows = []
    for n in args.num_envs:
        for row in measure_interleaved(envs, n, args.steps, args.rounds):
            print(
                f"{row['env']:28s} {n:6d} envs: compile {row['compile_s']:6.2f} s, "
                f"{row['steps_per_s']:14,.0f} steps/s",
                file=sys.stderr,
            )
            rows.append(row)
    add_ratios(rows)
    info["loadavg_1m_at_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    md = table(rows)
    cost = autoreset_cost(rows)
    if cost:
        md += "\n\nAuto-reset cost (steps/s of step_env only / GridMaze-v0): " + ", ".join(
            f"{n} envs {c:.2f}x" for n, c in cost.items()
        )
    print(md)
    result = {
        "machine": info,
        "steps": args.steps,
        "num_envs": args.num_envs,
        "skipped": skipped,
        "results": rows,
        "autoreset_cost": {str(n): c for n, c in cost.items()},
    }
    write_results(args.out, result, md)
    return result


if __name__ == "__main__":
    main()
