"""Environment throughput: env steps/s of ``jax.lax.scan`` over a batched ``env.step``.

    python -m benchmarks.env_throughput [--num-envs 1,16,256,4096,16384] [--steps N]
        [--target-s S] [--out benchmarks/results/env_throughput.json] [--envs NAME,NAME,...]

Each (env, num_envs) row jits one function that loops a given number of steps of the batched
step (``vmap(step)``; for our envs their ``step_batch``, the same results with fresh episodes
built only for the envs that ended) with uniformly random actions (per-step action and key
sampling included in the timing); the step count is an argument, so one compiled program serves
every count. The loop carries the observation and sums the reward, so XLA cannot drop the
observation computation.
"compile s" is trace + lower + XLA compile (``jit(f).lower(...).compile()``). Steps per timed
run: ``--steps``, or fewer when one step takes long enough that ``--target-s`` seconds are
reached sooner (timed once after the warm-up), so slow rows at large num_envs stay short.
steps/s uses the median of ``--rounds`` runs; the rows of one num_envs are timed in turn,
round by round, so load changes hit them alike and ratios stay meaningful. "peak bytes" is
XLA's peak memory of the compiled loop (``Compiled.memory_analysis``).

Rows (``ROWS``): ``GridMaze-v0``, ``GridMaze-Random-v0`` (auto-reset ``env.step``),
``GridMaze-v0 onehot`` (its observation one-hot encoded by the env: 66 int8 values, not 10),
``GridMaze-Random-v0 no waypoint`` (``waypoint_cells=0``, as before the waypoint became its
default; only when asked for),
``GridMaze-v0 step_env only`` (no time limit, no auto-reset: the cost of auto-reset is its
ratio to GridMaze-v0), the robot ``RobotRandom-v0 mjx`` / ``RobotRandom-v0 kinematic`` (a
random maze per episode, one backend each; ``RobotSimple-v0 ...`` too; the generalist
``RobotNav-v0 kinematic``, a maze of its bank per episode; ``... lidar_map``: its waypoint
from the robot's own map) and the peers, each
through its own ``make`` and auto-resetting ``step``: gymnax's ``FourRooms-misc`` and
``MetaMaze-misc`` (5-tuple), ``navix FourRooms`` (``Navix-FourRooms-v0``, a random layout per
reset) and ``jaxmarl JaxNav`` (jaxmarl's JaxNav with one agent, its 15 discrete actions and its
default 200-beam lidar and random maps). Peers that do not import are skipped with a note.
The ratio column compares with gymnax FourRooms-misc at the same num_envs when it was
measured in the same run, otherwise with GridMaze-v0.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

import jaxnav
from benchmarks.common import compile_timed, machine_info, time_in_turn, write_results

# (key, state, action) -> (obs, state, reward): one environment, or (in ``Row.batch_step``)
# a batch of them along the leading axis
StepFn = Callable[[jax.Array, Any, jax.Array], tuple[jax.Array, Any, jax.Array]]
ResetFn = Callable[[jax.Array], tuple[jax.Array, Any]]

STEP_ENV_ONLY = "GridMaze-v0 step_env only"
ONEHOT = "GridMaze-v0 onehot"
OUR_ENVS = ("GridMaze-v0", ONEHOT, "GridMaze-Random-v0", STEP_ENV_ONLY)
# GridMaze-Random-v0 as it was before the waypoint became its default (the cost of the waypoint
# is the ratio of the two rows); not a default row
NO_WAYPOINT = "GridMaze-Random-v0 no waypoint"
ROBOT_ENVS = tuple(
    f"{env} {backend}"
    for env in ("RobotRandom-v0", "RobotSimple-v0")
    for backend in ("mjx", "kinematic")
) + ("RobotNav-v0 kinematic",)
LIDAR_MAP = "RobotNav-v0 kinematic lidar_map"  # the waypoint from the robot's own map
GYMNAX_ENVS = ("FourRooms-misc", "MetaMaze-misc")
NAVIX = "navix FourRooms"
JAXMARL = "jaxmarl JaxNav"
PEER_ENVS = GYMNAX_ENVS + (NAVIX, JAXMARL)
ALL_ENVS = OUR_ENVS + (NO_WAYPOINT,) + ROBOT_ENVS + (LIDAR_MAP,) + PEER_ENVS
DEFAULT_ENVS = OUR_ENVS + GYMNAX_ENVS
DEFAULT_OUT = Path("benchmarks/results/env_throughput.json")


class Row(NamedTuple):
    """How one benchmark row resets and steps its env."""

    reset: ResetFn
    step: StepFn  # one environment
    num_actions: int
    # the batched step the row is timed with: ``vmap(step)``, or for our envs their
    # ``step_batch`` (the same results, fresh episodes built only for the envs that ended)
    batch_step: StepFn


def build(name: str) -> Row:
    """The ``Row`` of one row name; peer rows import their library here."""
    if name == NAVIX:
        import navix  # bench extra

        nenv = navix.make("Navix-FourRooms-v0")

        def nstep(key: jax.Array, timestep: Any, action: jax.Array) -> Any:
            timestep = nenv.step(timestep, action)  # navix keeps its own key in the state
            return timestep.observation, timestep, timestep.reward

        def nreset(key: jax.Array) -> tuple[jax.Array, Any]:
            timestep = nenv.reset(key)
            return timestep.observation, timestep

        return Row(nreset, nstep, len(nenv.action_set), jax.vmap(nstep))
    if name == JAXMARL:
        from jaxmarl.environments.jaxnav import JaxNav  # bench extra

        menv = JaxNav(num_agents=1, act_type="Discrete")
        (agent,) = menv.agents

        def mstep(key: jax.Array, state: Any, action: jax.Array) -> Any:
            obs, state, reward, _dones, _info = menv.step(key, state, {agent: action})
            return obs[agent], state, reward[agent]

        def mreset(key: jax.Array) -> tuple[jax.Array, Any]:
            obs, state = menv.reset(key)
            return obs[agent], state

        return Row(mreset, mstep, menv.agent_action_space().n, jax.vmap(mstep))
    if name in GYMNAX_ENVS:
        import gymnax  # bench extra; may be absent

        genv, gparams = gymnax.make(name)

        def gstep(key: jax.Array, state: Any, action: jax.Array) -> Any:
            obs, state, reward, _done, _info = genv.step(key, state, action, gparams)
            return obs, state, reward

        return Row(lambda k: genv.reset(k, gparams), gstep, genv.num_actions, jax.vmap(gstep))
    if name in ROBOT_ENVS:
        env_id, backend = name.split(" ")
        env, params = jaxnav.make(env_id, backend=backend)
    elif name == LIDAR_MAP:
        env, params = jaxnav.make("RobotNav-v0", backend="kinematic", lidar_map=0.25)
    elif name in (*OUR_ENVS, NO_WAYPOINT):
        by_row = {ONEHOT: {"obs_mode": "onehot"}, NO_WAYPOINT: {"waypoint_cells": 0}}
        overrides = by_row.get(name, {})
        env, params = jaxnav.make(name.split(" ")[0], **overrides)
    else:
        raise ValueError(f"unknown row {name!r}; rows: {', '.join(ALL_ENVS)}")
    reset = partial(env.reset, params=params)
    if name == STEP_ENV_ONLY:

        def step_env(key: jax.Array, state: Any, action: jax.Array) -> Any:
            obs, state, reward, _terminated, _info = env.step_env(key, state, action, params)
            return obs, state, reward

        return Row(reset, step_env, env.num_actions, jax.vmap(step_env))

    def step(key: jax.Array, state: Any, action: jax.Array) -> Any:
        obs, state, reward, _terminated, _truncated, _info = env.step(key, state, action, params)
        return obs, state, reward

    def batch_step(keys: jax.Array, state: Any, action: jax.Array) -> Any:
        obs, state, reward, _terminated, _truncated, _info = env.step_batch(
            keys, state, action, params
        )
        return obs, state, reward

    return Row(reset, step, env.num_actions, batch_step)


def prepare(
    name: str,
    num_envs: int,
    steps: int,
    target_s: float | None = None,
    seed: int = 0,
    devices: int = 1,
) -> dict[str, Any]:
    """Compile one row's rollout; returns a record with ``run()`` that times one execution of
    ``steps`` steps, or fewer if one step takes so long that ``target_s`` is reached sooner.
    With ``devices`` > 1 the envs are laid out evenly over that many devices, each stepping
    its own (``shard_map``; no communication but the reward sum)."""
    row = build(name)
    mesh = Mesh(np.array(jax.devices()[:devices]), ("envs",))
    vstep = row.batch_step
    if devices > 1:  # each device steps (and, in ``step_batch``, resets) its own envs
        vstep = jax.shard_map(vstep, mesh=mesh, in_specs=P("envs"), out_specs=P("envs"))

    def rollout(
        key: jax.Array, obs: jax.Array, state: Any, steps: jax.Array
    ) -> tuple[jax.Array, Any, jax.Array]:
        def body(i: jax.Array, carry: Any) -> Any:
            obs, state, total = carry
            k_act, k_step = jax.random.split(jax.random.fold_in(key, i))
            # one 32-bit word per action: randint draws two, doubling the harness cost
            actions = (jax.random.bits(k_act, (num_envs,)) % row.num_actions).astype(jnp.int32)
            obs, state, reward = vstep(jax.random.split(k_step, num_envs), state, actions)
            return obs, state, total + reward.astype(jnp.float32).sum()

        return jax.lax.fori_loop(0, steps, body, (obs, state, jnp.zeros((), jnp.float32)))

    k_reset, k_run = jax.random.split(jax.random.key(seed))
    reset_all = jax.jit(jax.vmap(row.reset), out_shardings=NamedSharding(mesh, P("envs")))
    obs, state = jax.block_until_ready(reset_all(jax.random.split(k_reset, num_envs)))
    program, compile_s = compile_timed(rollout, k_run, obs, state, jnp.int32(1))
    if target_s is not None:  # one step, warm: how many fit in target_s
        steps = int(np.clip(target_s / program(), 1, steps))
    n = jnp.int32(steps)
    return {
        "env": name,
        "num_envs": num_envs,
        "steps": steps,
        "compile_s": compile_s,
        "peak_bytes": program.peak_bytes,
        "run": lambda: program(k_run, obs, state, n),
    }


def measure_interleaved(
    names: list[str],
    num_envs: int,
    steps: int,
    rounds: int,
    target_s: float | None = None,
    out_of_memory: dict[str, str] | None = None,
) -> list[dict]:
    """Time every row ``rounds`` times in turn (row A, B, C, A, B, C, ...), so that a change of
    machine load hits all rows alike and the ratios stay meaningful; median per row.

    A row that runs out of device memory (at large ``num_envs`` on a GPU) is left out and
    noted in ``out_of_memory`` ("NAME @ N envs" -> the error's first line) when given, so one
    peer's reset cannot end the whole run; any other error is raised."""
    rows = []
    for name in names:
        try:
            rows.append(prepare(name, num_envs, steps, target_s))
        except Exception as e:  # noqa: BLE001 (XLA's runtime error type differs by version)
            if out_of_memory is None or not is_out_of_memory(e):
                raise
            out_of_memory[f"{name} @ {num_envs} envs"] = str(e).splitlines()[0][:300]
            print(f"{name} at {num_envs} envs: out of memory, left out", file=sys.stderr)
    time_in_turn(rows, rounds)
    for row in rows:
        row["steps_per_s"] = num_envs * row["steps"] / statistics.median(row["run_s"])
    return rows


def is_out_of_memory(error: Exception) -> bool:
    text = str(error)
    return "RESOURCE_EXHAUSTED" in text or "out of memory" in text.lower()


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
    p.add_argument("--steps", type=int, default=200, help="steps per timed run (at most)")
    p.add_argument("--target-s", type=float, help="fewer steps if a run would take longer")
    p.add_argument("--rounds", type=int, default=5, help="interleaved timed runs per row")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output path")
    p.add_argument("--envs", default=",".join(DEFAULT_ENVS), help=f"comma-separated of {ALL_ENVS}")
    args = p.parse_args(argv)
    args.num_envs = [int(n) for n in args.num_envs.split(",")]
    args.envs = [e.strip() for e in args.envs.split(",") if e.strip()]
    unknown = [e for e in args.envs if e not in ALL_ENVS]
    if unknown or args.steps < 1 or args.rounds < 1 or min(args.num_envs) < 1:
        p.error(f"unknown envs {unknown} (valid: {ALL_ENVS}), or steps/num_envs < 1")
    return args


def usable(names: list[str]) -> tuple[list[str], dict[str, str]]:
    """The rows whose library imports and traces on this jax, and why the others do not."""
    ok, skipped = [], {}
    for name in names:
        try:
            row = build(name)
            obs, state = jax.eval_shape(row.reset, jax.random.key(0))
            jax.eval_shape(row.step, jax.random.key(1), state, jnp.int32(0))
            ok.append(name)
        except Exception as e:  # a peer missing, or one that breaks on this jax
            print(f"note: {name} skipped ({type(e).__name__}: {e})", file=sys.stderr)
            skipped[name] = f"{type(e).__name__}: {e}"
    return ok, skipped


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the table, write the JSON (and a .md table next to it)."""
    args = parse_args(argv)
    info = machine_info()
    envs, skipped = usable(args.envs)
    rows = []
    for n in args.num_envs:
        for row in measure_interleaved(envs, n, args.steps, args.rounds, args.target_s):
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
