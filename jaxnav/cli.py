"""Command lines: ``python -m jaxnav.train`` and ``python -m jaxnav.evaluate``.

Bad input of any kind is one line on stderr naming the value, exit code 2, nothing written.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxnav import run_dir
from jaxnav.config import TrainConfig
from jaxnav.evaluate import evaluate_seeds, mean_of
from jaxnav.registration import registered_envs
from jaxnav.train import METRIC_NAMES, Trainer

HELP = {
    "env": f"environment id ({', '.join(registered_envs())})",
    "seed": "first seed; seeds are seed .. seed+num_seeds-1",
    "num_seeds": "seeds trained at once (vmapped in one program)",
    "total_timesteps": "env steps per seed",
    "num_envs": "parallel environments per seed",
    "hidden_sizes": "MLP widths, comma separated (the paper's: 512,256,128,64)",
    "dueling": "dueling heads V + A - mean(A) (paper eq. 7)",
    "double": "double-DQN targets (paper eq. 6)",
    "loss": "huber or mse",
    "buffer_size": "replay capacity in transitions",
    "batch_size": "transitions per gradient step",
    "learning_starts": "env steps of random actions before the first update",
    "updates_per_iteration": "gradient steps per vectorized env step",
    "n_step": "n-step returns",
    "gamma": "discount",
    "lr": "learning rate at the start",
    "lr_end": "learning rate at the end (linear decay)",
    "optimizer": "adam or sgd",
    "max_grad_norm": "global-norm gradient clipping",
    "target_update_period": "env steps between target-network updates",
    "tau": "target update weight (1 = hard copy)",
    "eps_start": "exploration epsilon at the start",
    "eps_end": "exploration epsilon after eps_decay_steps",
    "eps_decay_steps": "env steps of linear epsilon decay",
    "log_interval": "env steps per metrics row and progress line",
    "eval_episodes": "greedy evaluation episodes at the end",
}


class UsageError(Exception):
    """Bad command-line input: reported as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, no usage dump
        raise UsageError(message)


def _bool(text: str) -> bool:
    t = text.lower()
    if t in ("true", "1", "yes", "on"):
        return True
    if t in ("false", "0", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"invalid boolean {text!r} (use true or false)")


def _int_list(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid list of integers {text!r}") from None


def _env_arg(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"invalid override {text!r} (use KEY=VALUE)")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value  # a bare string, e.g. obs_mode=paper


def _add_env_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--env-arg",
        type=_env_arg,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="environment override, repeatable (e.g. size=11, obs_mode=paper)",
    )


def train_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="python -m jaxnav.train",
        description="Train a (dueling, double) DQN; all seeds and the whole run are one program.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    defaults = TrainConfig()
    for f in dataclasses.fields(TrainConfig):
        if f.name == "env_kwargs":
            continue
        default = getattr(defaults, f.name)
        flag = "--" + f.name.replace("_", "-")
        if isinstance(default, bool):
            kind, meta = _bool, "{true,false}"
        elif isinstance(default, tuple):
            kind, meta, default = _int_list, "W,W,...", ",".join(map(str, default))
        else:
            kind, meta = type(default), None
        p.add_argument(flag, type=kind, default=default, metavar=meta, help=HELP.get(f.name))
    _add_env_args(p)
    p.add_argument("--out", type=Path, help="run directory (default: runs/<env>-<time>)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    values = {}
    for f in dataclasses.fields(TrainConfig):
        if f.name != "env_kwargs":
            v = getattr(args, f.name)
            values[f.name] = _int_list(v) if f.name == "hidden_sizes" and isinstance(v, str) else v
    values["env_kwargs"] = dict(args.env_arg)
    return TrainConfig(**values)


class Progress:
    """Progress lines, one per logging interval, printed between the compiled intervals."""

    def __init__(self, config: TrainConfig, quiet: bool):
        self.config, self.quiet = config, quiet
        self.times: dict[int, float] = {}
        self.start = time.perf_counter()

    def __call__(self, metrics: dict[str, np.ndarray]) -> None:
        """``metrics`` of one logging interval, every seed (leading axis)."""
        steps = int(np.ravel(metrics["env_steps"])[0])
        now = time.perf_counter()
        self.times[steps] = now
        if self.quiet:
            return
        elapsed = now - self.start
        total = self.config.num_logs * self.config.iterations_per_log * self.config.num_envs
        sps = steps * self.config.num_seeds / max(elapsed, 1e-9)
        eta = (total - steps) * self.config.num_seeds / max(sps, 1e-9)
        mean = lambda k: float(np.mean(metrics[k]))  # noqa: E731
        print(
            f"[{elapsed:6.1f}s] steps {steps:>9,}/{total:,} ({100 * steps / total:3.0f}%) | "
            f"{sps:>8,.0f} steps/s | success {mean('success_rate'):.3f} | "
            f"return {mean('mean_return'):6.2f} | length {mean('mean_length'):5.1f} | "
            f"loss {mean('loss'):.4f} | eps {mean('epsilon'):.2f} | ETA {eta:4.0f}s",
            flush=True,
        )

    def steps_per_second(self, env_steps: np.ndarray) -> np.ndarray:
        """Env steps/s (all seeds) of each logging interval, from the callback times."""
        times = [self.start] + [self.times.get(int(s), np.nan) for s in env_steps]
        dt = np.diff(np.asarray(times))
        interval = self.config.iterations_per_log * self.config.num_envs * self.config.num_seeds
        return interval / dt


def enable_compilation_cache() -> None:
    """Persist compiled programs across runs (``JAXNAV_CACHE_DIR``, default
    ``~/.cache/jaxnav/xla``; set it to an empty string to disable): a second run of the same
    config skips XLA compilation."""
    path = os.environ.get("JAXNAV_CACHE_DIR", str(Path.home() / ".cache" / "jaxnav" / "xla"))
    if path:
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def _fail(prog: str, message: str) -> int:
    print(f"{prog}: error: {message}", file=sys.stderr)
    return 2


def train_seeds(
    trainer: Trainer, keys: jax.Array, progress: Progress
) -> tuple[Any, dict[str, np.ndarray], float, float]:
    """Train every seed of ``keys`` at once; ``(final state, metrics [seeds, logs], compile
    seconds, train seconds)``, with a progress line per logging interval.

    One compiled logging interval, called once per interval, with progress printed in
    between: a host callback inside the program would keep XLA's persistent cache from
    storing it (JAX does not cache programs with host callbacks).
    """
    t0 = time.perf_counter()
    init = jax.jit(jax.vmap(trainer.init)).lower(keys).compile()
    one_interval = jax.vmap(lambda ts, log: trainer.run(ts, log, 1), in_axes=(0, None))
    state_like = jax.eval_shape(jax.vmap(trainer.init), keys)
    log_like = jax.ShapeDtypeStruct((), np.int32)
    interval = jax.jit(one_interval, donate_argnums=0).lower(state_like, log_like).compile()
    compile_s = time.perf_counter() - t0
    print(f"compiled in {compile_s:.1f}s", flush=True)
    progress.start = t0 = time.perf_counter()
    state, chunks = init(keys), []
    for log in range(trainer.config.num_logs):
        state, chunk = interval(state, np.int32(log))
        chunks.append(jax.device_get(chunk))  # [seeds, 1] each
        progress(chunks[-1])
    train_s = time.perf_counter() - t0
    metrics = {k: np.concatenate([c[k] for c in chunks], axis=1) for k in METRIC_NAMES}
    return state, metrics, compile_s, train_s


def train_main(argv: Sequence[str] | None = None) -> int:
    prog = "jaxnav.train"
    t_start = time.perf_counter()
    try:
        args = train_parser().parse_args(argv)
        config = config_from_args(args)
        config.validate()
        out = args.out or Path("runs") / f"{config.env}-{time.strftime('%Y%m%d-%H%M%S')}"
        run_dir.check_writable(out)
        progress = Progress(config, args.quiet)
        trainer = Trainer(config)
    except (UsageError, ValueError) as e:
        return _fail(prog, str(e))

    enable_compilation_cache()
    keys = run_dir.seed_keys(config)
    print(
        f"training {config.env} for {config.total_timesteps:,} steps x {config.num_seeds} "
        f"seed(s), {config.num_envs} envs each -> {out}",
        flush=True,
    )
    state, metrics, compile_s, train_s = train_seeds(trainer, keys, progress)
    metrics["sps"] = np.broadcast_to(
        progress.steps_per_second(metrics["env_steps"][0]), metrics["env_steps"].shape
    )
    t0 = time.perf_counter()
    trained = evaluate_seeds(trainer, state.params, config.eval_episodes, seed=10_000)
    rand = evaluate_seeds(trainer, state.params, config.eval_episodes, 10_000, "random")
    eval_s = time.perf_counter() - t0

    # write into a hidden sibling, then rename: a crash never leaves half a run behind
    partial = out.with_name(f".{out.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    run_dir.write_json(partial / "config.json", run_dir.config_document(config, trainer))
    run_dir.write_metrics_csv(partial / "metrics.csv", metrics, run_dir.seeds_of(config))
    run_dir.save_params(partial, state.params)
    summary = {
        "env": config.env,
        "seeds": run_dir.seeds_of(config),
        "eval_episodes": config.eval_episodes,
        "trained": mean_of(trained),
        "trained_per_seed": trained,
        "random_policy": mean_of(rand),
        "compile_s": compile_s,
        "train_s": train_s,
        "eval_s": eval_s,
        "wall_s": time.perf_counter() - t_start,
    }
    run_dir.write_json(partial / "summary.json", summary)
    if out.exists():
        out.rmdir()  # checked empty before training
    partial.rename(out)
    print_eval_table(
        config.env, {"trained (greedy)": summary["trained"], "random": summary["random_policy"]}
    )
    print(
        f"compile {compile_s:.1f}s, train {train_s:.1f}s, eval {eval_s:.1f}s, "
        f"total {summary['wall_s']:.1f}s; run saved to {out}"
    )
    return 0


def print_eval_table(env: str, rows: dict[str, dict[str, float]]) -> None:
    cols = (
        "success_rate",
        "collision_rate",
        "timeout_rate",
        "mean_return",
        "mean_steps",
        "mean_path_ratio",
    )
    print(f"\n{env}: {next(iter(rows.values()))['episodes']:.0f} episodes per policy")
    print("| policy | " + " | ".join(cols) + " |")
    print("|---" * (len(cols) + 1) + "|")
    for name, r in rows.items():
        print(f"| {name} | " + " | ".join(f"{r[c]:.3f}" for c in cols) + " |")


def evaluate_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="python -m jaxnav.evaluate",
        description="Evaluate a trained run (greedy) or the random agent on fresh episodes.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("run", type=Path, help="run directory written by jaxnav.train")
    p.add_argument("--env", help="evaluate on another env id (generalization); default: the run's")
    _add_env_args(p)
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0, help="seed of the test episodes")
    p.add_argument("--policy", choices=("trained", "random"), default="trained")
    p.add_argument("--out", type=Path, help="output JSON (default: RUN/eval.json)")
    return p


def evaluate_main(argv: Sequence[str] | None = None) -> int:
    prog = "jaxnav.evaluate"
    try:
        args = evaluate_parser().parse_args(argv)
        if not 1 <= args.episodes <= 10**7:
            raise ValueError(f"--episodes {args.episodes}: must be in [1, 10000000]")
        if args.seed < 0:
            raise ValueError(f"--seed {args.seed}: must be non-negative")
        config = run_dir.load_config(args.run)
        env_kwargs = {**(config.env_kwargs if args.env is None else {}), **dict(args.env_arg)}
        config = dataclasses.replace(config, env=args.env or config.env, env_kwargs=env_kwargs)
        config.validate()
        trainer = Trainer(config)
        want = (run_dir.load_network(args.run)["obs_size"],)
        if trainer.env.observation_space().shape != want:
            raise ValueError(
                f"--env {config.env}: observations of shape "
                f"{trainer.env.observation_space().shape} do not fit the run's network {want}"
            )
        out = args.out or args.run / "eval.json"
        if not out.parent.is_dir():
            raise ValueError(f"--out {out}: directory {out.parent} does not exist")
        params = run_dir.load_trained_params(args.run, trainer)
    except (UsageError, ValueError, FileNotFoundError) as e:
        return _fail(prog, str(e))
    enable_compilation_cache()
    rows = evaluate_seeds(trainer, params, args.episodes, args.seed, args.policy)
    result = {
        "run": str(args.run),
        "env": config.env,
        "env_kwargs": config.env_kwargs,
        "policy": args.policy,
        "episodes": args.episodes,
        "seed": args.seed,
        **mean_of(rows),
        "per_seed": rows,
    }
    run_dir.write_json(out, result)
    print_eval_table(config.env, {args.policy: mean_of(rows)})
    print(f"wrote {out}")
    return 0
