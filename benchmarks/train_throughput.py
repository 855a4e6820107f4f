"""Training throughput: env steps/s of DQN and PQN training against num_envs, beside two bounds.

    python -m benchmarks.train_throughput [--algos dqn,pqn] [--env GridMaze-v0]
        [--env-arg KEY=VALUE ...] [--num-envs 16,64,256] [--iterations 50]
        [--rollout-length L] [--num-minibatches M] [--num-epochs E]      (PQN)
        [--batch-size B] [--replay-ratio R]                               (DQN)
        [--hidden-sizes W,W,...] [--compute-dtype float32|bfloat16] [--seed 0]
        [--out benchmarks/results/train_throughput.json]

Every row is ``TrainConfig.for_env(env, algo=...)`` (the preset of that algorithm and env,
``jaxnav.presets``) with the given num_envs and knobs; a knob left out keeps the preset's
value, PQN's knobs apply to PQN only and DQN's to DQN only. So that every timed iteration
learns, ``log_interval`` is ``--iterations`` iterations and DQN's ``learning_starts`` is
``num_envs * n_step`` (its buffer at least that large); DQN's replay buffer is filled with
random-action transitions of the env before any timing (``prep s``), so sampling reads a
full-size buffer as in the second half of a real run.

Three programs per (num_envs, algo), each compiled once (``jit(f).lower(...).compile()``,
compile seconds reported apart), called once untimed, then timed 3 times (median reported),
the programs of one num_envs in turn (A, B, C, A, B, C, ...) so load changes hit them alike.
The state argument is donated and each call continues from the previous one's state, as the
consecutive chunks of a training run do.

- ``train``: ``Trainer.run(state, log, 1)``: ``--iterations`` training iterations (acting,
  the vectorized env step with auto-reset, and the algorithm's learning step: replay write,
  sampling, gradient steps and target updates for DQN; lambda-returns, shuffles and
  ``num_epochs * num_minibatches`` gradient steps for PQN) -> env steps/s.
- ``env alone`` (one per num_envs, shared by the algorithms): a scan of the same
  ``vmap(env.step)`` with uniformly random actions, no network, as many vectorized steps as the
  longest training run or, where that takes under 0.2 s, enough for 0.2 s (timed once after
  the untimed call) -> env steps/s. Training cannot beat it.
- ``update`` (the bare network update): a scan of ``Trainer.gradient_step`` with
  ``Trainer.minibatch_loss`` (the same network, loss and optimizer) on a fixed minibatch of
  the training's size (PQN: ``num_envs * rollout_length / num_minibatches``; DQN:
  ``batch_size``, sampled once from the filled buffer), rolled by one row per step so XLA
  cannot hoist loop-invariant work, as many steps as the training run takes -> updates/s,
  and the env steps/s training would reach if updates were all it did:
  updates/s * steps_per_iteration / updates_per_iteration (DQN: replay_ratio * num_envs /
  batch_size, so at the preset's replay ratio it grows with num_envs). Training cannot beat it
  either.

Fractions: training env steps/s over each bound, and over the ``serial`` bound
1 / (1 / env alone + 1 / update), the rate if training cost exactly the two added up (acting,
replay and returns are the rest). Writes the JSON, a markdown table beside it (``.md``) and a
plot (``.png``): env steps/s against num_envs, log-log, per algorithm (its update bound
dotted) and the env-alone bound.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from benchmarks.common import machine_info, machine_text, write_results
from jaxnav.agents import dqn
from jaxnav.agents.dqn import COMPUTE_DTYPES
from jaxnav.cli import one_line, parse_bool, parse_env_arg
from jaxnav.config import MAX_STEPS, TrainConfig
from jaxnav.train import Trainer, TrainState, jit_training

DEFAULT_OUT = Path("benchmarks/results/train_throughput.json")
# the algorithms whose update ``fixed_minibatch`` and ``update_program`` time: one network's
# gradient step on a Q-learning minibatch
ALGOS = ("dqn", "pqn")
ROUNDS = 3  # timed calls per program; the median is reported
ENV_ALONE = "env alone"
ENV_MIN_S = 0.2  # seconds of a timed env-alone run, at least
PQN_KNOBS = ("rollout_length", "num_minibatches", "num_epochs")
DQN_KNOBS = ("batch_size", "replay_ratio")
SHARED_KNOBS = ("hidden_sizes", "compute_dtype", "layer_norm", "fused_layer_norm")


def first_timed_log(config: TrainConfig) -> int:
    """The first logging interval whose iterations all learn."""
    return -(-config.first_learning_iteration // config.iterations_per_log)


def make_config(
    algo: str,
    env: str,
    env_kwargs: dict[str, Any],
    num_envs: int,
    iterations: int,
    knobs: dict[str, Any],
) -> TrainConfig:
    """The preset of (algo, env) with ``num_envs``, this algorithm's ``knobs`` (None: the
    preset's), a logging interval of ``iterations`` iterations and, for DQN, learning from the
    first iteration on."""
    own = SHARED_KNOBS + (PQN_KNOBS if algo == "pqn" else DQN_KNOBS)
    given = {k: v for k, v in knobs.items() if k in own and v is not None}
    config = TrainConfig.for_env(
        env, algo=algo, env_kwargs=dict(env_kwargs), num_envs=num_envs, **given
    )
    return timed_config(config, iterations, ROUNDS)


def timed_config(config: TrainConfig, iterations: int, rounds: int) -> TrainConfig:
    """``config`` with a logging interval of ``iterations`` iterations, room for an untimed
    call and ``rounds`` timed ones after the first interval that learns, and, for DQN,
    learning from the first iteration on."""
    extra: dict[str, Any] = {"log_interval": iterations * config.steps_per_iteration}
    if config.algo == "dqn":
        starts = config.num_envs * config.n_step
        extra |= {
            "learning_starts": starts,
            "buffer_size": max(config.buffer_size, starts, config.batch_size),
        }
    config = dataclasses.replace(config, **extra)
    # room for the untimed call and the timed ones (the learning-rate schedule spans them)
    runs = first_timed_log(config) + rounds + 1
    if runs * config.steps_per_log > MAX_STEPS:
        raise ValueError(
            f"num_envs={config.num_envs}, --iterations {iterations}: the {runs} runs of "
            f"{config.algo} would take {runs * config.steps_per_log} env steps, more than the "
            f"{MAX_STEPS} that training counts (int32); use fewer iterations"
        )
    config = dataclasses.replace(config, total_timesteps=runs * config.steps_per_log)
    config.validate()
    return config


def compile_donating(fn: Callable[[Any, Any], Any], state: Any, arg: Any) -> tuple[Any, float]:
    """``jit(fn, donate_argnums=0)`` lowered and compiled; returns it and the seconds taken."""
    t0 = time.perf_counter()
    compiled = jit_training(fn, donate_argnums=0).lower(state, arg).compile()
    return compiled, time.perf_counter() - t0


def filled_state(trainer: Trainer, key: jax.Array) -> TrainState:
    """``trainer.init`` then ``buffer_rows`` vectorized steps of random-action transitions
    written to the replay buffer (what an eps = 1 warm-up writes). One jitted function."""
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
        init = (ts.algo_state.buffer, ts.env_state, ts.obs)
        keys = jax.random.split(k_fill, ts.algo_state.buffer.capacity)
        (buf, env_state, obs), _ = jax.lax.scan(body, init, keys)
        algo_state = ts.algo_state.replace(buffer=buf)
        return ts.replace(algo_state=algo_state, env_state=env_state, obs=obs)

    return jax.block_until_ready(fill(key))


def fixed_minibatch(trainer: Trainer, ts: TrainState, key: jax.Array) -> Any:
    """One minibatch of the training's size and layout (``Trainer.minibatch_loss``): DQN's
    sampled from the filled buffer, PQN's real observations of freshly reset envs with random
    actions and targets."""
    c = trainer.config
    if c.algo == "dqn":
        sample = jax.jit(dqn.buffer_sample, static_argnums=(2, 3))
        return sample(ts.algo_state.buffer, key, c.batch_size, c.n_step, ts.hparams.gamma)
    k_reset, k_act, k_target = jax.random.split(key, 3)
    b = c.minibatch_size
    reset = jax.jit(jax.vmap(trainer.env.reset, in_axes=(0, None)))
    obs, _ = reset(jax.random.split(k_reset, b), trainer.env_params)
    action = jax.random.randint(k_act, (b,), 0, trainer.env.num_actions)
    return obs, action, jax.random.normal(k_target, (b,))


def update_program(trainer: Trainer, num_updates: int) -> Callable[[TrainState, Any], Any]:
    """``(state, batch) -> (state, mean loss)``: ``num_updates`` of ``Trainer.gradient_step``
    on ``batch``, rolled by one row each step, its diagnostics summed as training sums them
    (``dqn.diagnostics_add``)."""

    def run(ts: TrainState, batch: Any) -> tuple[TrainState, jax.Array]:
        loss_fn = trainer.minibatch_loss(ts)
        rows = jax.tree.leaves(batch)[0].shape[0]

        def step(carry: tuple[TrainState, Any, dict], _: None) -> tuple[tuple, None]:
            ts, batch, total = carry
            ts, diagnostics = trainer.gradient_step(ts, batch, loss_fn)
            batch = jax.tree.map(lambda x: jnp.roll(x, 1, axis=0), batch)
            return (ts, batch, dqn.diagnostics_add(total, diagnostics)), None

        carry = (ts, batch, dqn.diagnostics_init(rows))
        (ts, _, total), _ = jax.lax.scan(step, carry, None, length=num_updates)
        return ts, dqn.diagnostics_means(total, num_updates)["loss"]

    return run


def env_program(trainer: Trainer) -> Callable[[tuple, tuple], Any]:
    """``((obs, env_state), (key, steps)) -> ((obs, env_state), reward sum)``: ``steps``
    (traced: one program for every count) vectorized steps of the training's
    ``vmap(env.step)`` with uniformly random actions."""
    env, params, n = trainer.env, trainer.env_params, trainer.config.num_envs
    vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def run(carry: tuple, arg: tuple[jax.Array, jax.Array]) -> tuple[tuple, jax.Array]:
        key, steps = arg

        def body(i: jax.Array, carry: tuple) -> tuple:
            obs, state, total = carry
            k_act, k_step = jax.random.split(jax.random.fold_in(key, i))
            action = jax.random.randint(k_act, (n,), 0, env.num_actions)
            obs, state, reward, _term, _trunc, _info = vstep(
                jax.random.split(k_step, n), state, action, params
            )
            return obs, state, total + reward.astype(jnp.float32).sum()

        obs, state = carry
        obs, state, total = jax.lax.fori_loop(0, steps, body, (obs, state, jnp.float32(0)))
        return (obs, state), total

    return run


@dataclasses.dataclass
class Program:
    """A compiled program with donated state: ``call(i)`` runs it on ``args[i]`` from the
    state the previous call left, and records wall and process CPU seconds."""

    compiled: Any
    state: Any
    args: list[Any]
    compile_s: float
    run_s: list[float] = dataclasses.field(default_factory=list)
    cpu_s: list[float] = dataclasses.field(default_factory=list)

    def call(self, i: int, timed: bool = True) -> None:
        t0, c0 = time.perf_counter(), time.process_time()
        self.state, _ = jax.block_until_ready(self.compiled(self.state, self.args[i]))
        if timed:
            self.run_s.append(time.perf_counter() - t0)
            self.cpu_s.append(time.process_time() - c0)

    def record(self) -> dict[str, Any]:
        return {"compile_s": self.compile_s, "run_s": self.run_s, "cpu_s": self.cpu_s}


def time_in_turn(programs: dict[str, Program]) -> None:
    """One untimed call of each program, then ``ROUNDS`` timed calls of each, in turn."""
    for p in programs.values():
        p.call(0, timed=False)
    for r in range(1, ROUNDS + 1):
        for p in programs.values():
            p.call(r)


def measure(
    trainers: dict[str, Trainer], iterations: int, seed: int = 0
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Compile and time the env alone and, per algorithm, training and the bare update, all of
    one num_envs (``trainers``: algo -> its trainer); returns the env-alone record and a row
    per algorithm."""
    any_trainer = next(iter(trainers.values()))
    num_envs = any_trainer.config.num_envs
    key = jax.random.key(seed)
    k_env, k_env_runs, key = jax.random.split(key, 3)
    programs: dict[str, Program] = {}
    prep_s: dict[str, float] = {}

    # as many vectorized steps as the longest training run, or more where that run would
    # take less than ENV_MIN_S (a few ms at small num_envs: too short to time)
    env_steps = iterations * max(t.config.rollout_length for t in trainers.values())
    reset = jax.jit(jax.vmap(any_trainer.env.reset, in_axes=(0, None)))
    carry = reset(jax.random.split(k_env, num_envs), any_trainer.env_params)
    env_keys = list(jax.random.split(k_env_runs, ROUNDS + 1))
    env_arg = (env_keys[0], jnp.int32(env_steps))
    compiled, compile_s = compile_donating(env_program(any_trainer), carry, env_arg)
    env = Program(compiled, carry, [env_arg], compile_s)
    env.call(0, timed=False)  # warm
    env.call(0)
    env_steps = max(env_steps, math.ceil(env_steps * ENV_MIN_S / env.run_s.pop()))
    env.cpu_s.pop()
    env.args = [(k, jnp.int32(env_steps)) for k in env_keys]
    programs[ENV_ALONE] = env

    for algo, trainer in trainers.items():
        c = trainer.config
        k_state, k_batch, key = jax.random.split(key, 3)
        t0 = time.perf_counter()
        ts = filled_state(trainer, k_state) if algo == "dqn" else jax.jit(trainer.init)(k_state)
        batch = jax.block_until_ready(fixed_minibatch(trainer, ts, k_batch))
        prep_s[algo] = time.perf_counter() - t0
        first = first_timed_log(c)
        logs = [jnp.asarray(first + i, jnp.int32) for i in range(ROUNDS + 1)]
        # one seed without a seed axis, as the training CLI compiles it (``Trainer.sharded``)
        train_ts = jax.tree.map(jnp.copy, ts)  # a copy: the program donates it
        compiled, compile_s = compile_donating(
            lambda ts, log, trainer=trainer: trainer.run(ts, log, 1), train_ts, logs[0]
        )
        programs[f"{algo} train"] = Program(compiled, train_ts, logs, compile_s)
        algo_state = ts.algo_state and ts.algo_state.replace(buffer=None)  # reads no buffer
        update_ts = jax.tree.map(jnp.copy, ts.replace(algo_state=algo_state))
        num_updates = iterations * c.updates_per_learning_iteration
        compiled, compile_s = compile_donating(
            update_program(trainer, num_updates), update_ts, batch
        )
        programs[f"{algo} update"] = Program(compiled, update_ts, [batch] * (ROUNDS + 1), compile_s)

    time_in_turn(programs)

    env = programs[ENV_ALONE]
    env_sps = env_steps * num_envs / statistics.median(env.run_s)
    env_record = {"num_envs": num_envs, "steps": env_steps, "env_steps_per_s": env_sps}
    env_record |= env.record()
    rows = []
    for algo, trainer in trainers.items():
        c = trainer.config
        train, update = programs[f"{algo} train"], programs[f"{algo} update"]
        steps = iterations * c.steps_per_iteration  # env steps of one training run
        train_t, update_t = statistics.median(train.run_s), statistics.median(update.run_s)
        updates = iterations * c.updates_per_learning_iteration
        train_sps, update_sps = steps / train_t, steps / update_t
        serial_sps = 1.0 / (1.0 / env_sps + 1.0 / update_sps)
        rows.append(
            {
                "algo": algo,
                "num_envs": num_envs,
                "iterations": iterations,
                "steps_per_iteration": c.steps_per_iteration,
                "minibatch_size": c.minibatch_size,
                "updates_per_iteration": c.updates_per_learning_iteration,
                "prep_s": prep_s[algo],
                "train": train.record()
                | {
                    "env_steps": steps,
                    "env_steps_per_s": train_sps,
                    "iterations_per_s": iterations / train_t,
                    "updates_per_s": updates / train_t,
                },
                "update": update.record()
                | {
                    "updates": updates,
                    "updates_per_s": updates / update_t,
                    "env_steps_per_s": update_sps,
                },
                "env_alone_steps_per_s": env_sps,
                "serial_bound_steps_per_s": serial_sps,
                "fraction_of_env_alone": train_sps / env_sps,
                "fraction_of_update": train_sps / update_sps,
                "fraction_of_serial": train_sps / serial_sps,
                "config": dataclasses.asdict(c),
            }
        )
    return env_record, rows


def _frac(x: float) -> str:
    return f"{x:.2f}" if x >= 0.1 else f"{x:.2g}"


def markdown(result: dict[str, Any]) -> str:
    """The head line (env, network, run length, machine) and the table of ``result``."""
    first = result["results"][0]["config"]
    kwargs = "".join(f" {k}={v}" for k, v in result["env_kwargs"].items())
    m = result["machine"]
    norm = "no LayerNorm"
    if first["layer_norm"]:
        norm = "fused LayerNorm" if first["fused_layer_norm"] else "flax's LayerNorm"
    head = (
        f"{result['env']}{kwargs}, network {'-'.join(map(str, first['hidden_sizes']))} "
        f"{first['compute_dtype']} with {norm}, {result['iterations']} iterations per timed "
        f"run, median of {result['rounds']}; {machine_text(m)}, {m['date'][:10]}"
    )
    return head + "\n\n" + table(result["results"], result["env_alone"])


def table(rows: list[dict[str, Any]], env_alone: list[dict[str, Any]]) -> str:
    compile_env = {e["num_envs"]: e["compile_s"] for e in env_alone}
    lines = [
        "| algo | num_envs | minibatch | updates / iteration | train env steps/s "
        "| env alone steps/s | of env alone | update bound env steps/s (updates/s) "
        "| of update | of serial | compile s (train / update / env) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        t, u = r["train"], r["update"]
        lines.append(
            f"| {r['algo']} | {r['num_envs']} | {r['minibatch_size']} | "
            f"{r['updates_per_iteration']} | {t['env_steps_per_s']:,.0f} | "
            f"{r['env_alone_steps_per_s']:,.0f} | {_frac(r['fraction_of_env_alone'])} | "
            f"{u['env_steps_per_s']:,.0f} ({u['updates_per_s']:,.0f}) | "
            f"{_frac(r['fraction_of_update'])} | {_frac(r['fraction_of_serial'])} | "
            f"{t['compile_s']:.1f} / {u['compile_s']:.1f} / {compile_env[r['num_envs']]:.1f} |"
        )
    return "\n".join(lines)


def plot(result: dict[str, Any], out: Path) -> None:
    """Env steps/s against num_envs, log-log: training per algorithm (solid), its update
    bound (dotted, same colour) and the env-alone bound (black, dashed)."""
    rows, env_alone, m = result["results"], result["env_alone"], result["machine"]
    title = (
        f"{result['env']}: training env steps/s and its bounds; {machine_text(m)}, "
        f"{m['date'][:10]}"
    )
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for i, algo in enumerate(dict.fromkeys(r["algo"] for r in rows)):
        own = sorted((r for r in rows if r["algo"] == algo), key=lambda r: r["num_envs"])
        xs = [r["num_envs"] for r in own]
        colour = f"C{i}"
        ax.plot(xs, [r["train"]["env_steps_per_s"] for r in own], "o-", color=colour,
                label=f"{algo} training")  # fmt: skip
        ax.plot(xs, [r["update"]["env_steps_per_s"] for r in own], ":", color=colour,
                label=f"{algo} bare update bound")  # fmt: skip
    env = sorted(env_alone, key=lambda e: e["num_envs"])
    ax.plot([e["num_envs"] for e in env], [e["env_steps_per_s"] for e in env], "s--",
            color="black", label="env alone (random actions)")  # fmt: skip
    ax.set(xscale="log", yscale="log", xlabel="parallel envs", ylabel="env steps / s")
    sizes = sorted(e["num_envs"] for e in env)
    ax.set_xticks(sizes, [str(n) for n in sizes])
    ax.minorticks_off()
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit code 2, no usage dump
        self.exit(2, f"{self.prog}: error: {one_line(message)}\n")


def _ints(flag: str, text: str, p: argparse.ArgumentParser) -> list[int]:
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        values = []
    if not values or min(values) < 1:
        p.error(f"{flag} {text!r}: comma-separated integers >= 1")
    return values


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = Parser(prog="python -m benchmarks.train_throughput", description=__doc__.splitlines()[0])
    p.add_argument("--algos", default="dqn,pqn", help=f"comma-separated of {', '.join(ALGOS)}")
    p.add_argument("--env", default="GridMaze-v0", help="registered env id")
    p.add_argument("--env-arg", type=parse_env_arg, action="append", default=[],
                   metavar="KEY=VALUE", help="environment override, repeatable")  # fmt: skip
    p.add_argument("--num-envs", default="16,64,256", help="comma-separated")
    p.add_argument("--iterations", type=int, default=50, help="training iterations per run")
    p.add_argument("--seed", type=int, default=0)
    knob = "(default: the preset's)"
    p.add_argument("--rollout-length", type=int, help=f"PQN {knob}")
    p.add_argument("--num-minibatches", type=int, help=f"PQN {knob}")
    p.add_argument("--num-epochs", type=int, help=f"PQN {knob}")
    p.add_argument("--batch-size", type=int, help=f"DQN {knob}")
    p.add_argument(
        "--replay-ratio", type=float, help=f"DQN sampled transitions per env step {knob}"
    )
    p.add_argument("--hidden-sizes", help=f"comma-separated MLP widths {knob}")
    p.add_argument("--compute-dtype", choices=COMPUTE_DTYPES, help=knob)
    p.add_argument("--layer-norm", type=parse_bool, metavar="{true,false}", help=knob)
    p.add_argument("--fused-layer-norm", type=parse_bool, metavar="{true,false}", help=knob)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output path")
    args = p.parse_args(argv)
    args.algos = list(dict.fromkeys(a.strip() for a in args.algos.split(",") if a.strip()))
    if not args.algos or any(a not in ALGOS for a in args.algos):
        p.error(f"--algos {','.join(args.algos)!r}: comma-separated of {', '.join(ALGOS)}")
    args.num_envs = _ints("--num-envs", args.num_envs, p)
    if args.iterations < 1:
        p.error(f"--iterations {args.iterations}: must be >= 1")
    if args.hidden_sizes is not None:
        args.hidden_sizes = tuple(_ints("--hidden-sizes", args.hidden_sizes, p))
    args.env_kwargs = dict(args.env_arg)
    args.knobs = {k: getattr(args, k) for k in SHARED_KNOBS + PQN_KNOBS + DQN_KNOBS}
    try:  # every config of the run, validated (and its memory checked) before any compile
        args.trainers = {
            n: {
                a: Trainer(
                    make_config(a, args.env, args.env_kwargs, n, args.iterations, args.knobs)
                )
                for a in args.algos
            }
            for n in args.num_envs
        }
    except (ValueError, TypeError) as e:  # unknown env or env argument, invalid value
        p.error(str(e))
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the table, write the JSON, the .md table and the .png plot."""
    args = parse_args(argv)
    info = machine_info()
    info.pop("gymnax_version", None)
    given = sys.argv[1:] if argv is None else argv
    command = " ".join(["python -m benchmarks.train_throughput", *given])
    env_alone, rows = [], []
    for n in args.num_envs:
        env_record, algo_rows = measure(args.trainers[n], args.iterations, args.seed)
        env_alone.append(env_record)
        for r in algo_rows:
            print(
                f"{r['algo']} {n:7d} envs: train {r['train']['env_steps_per_s']:12,.0f} "
                f"env steps/s = {_frac(r['fraction_of_env_alone'])} of env alone "
                f"({env_record['env_steps_per_s']:,.0f}), {_frac(r['fraction_of_update'])} of "
                f"the bare update ({r['update']['env_steps_per_s']:,.0f})",
                file=sys.stderr,
            )
        rows += algo_rows
    info["loadavg_1m_at_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    result = {
        "machine": info,
        "command": command,
        "env": args.env,
        "env_kwargs": args.env_kwargs,
        "algos": args.algos,
        "num_envs": args.num_envs,
        "iterations": args.iterations,
        "rounds": ROUNDS,
        "env_alone": env_alone,
        "results": rows,
    }
    md = markdown(result)
    print(md)
    write_results(args.out, result, md)
    plot(result, args.out.with_suffix(".png"))
    return result


if __name__ == "__main__":
    main()
