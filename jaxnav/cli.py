"""Command lines: ``python -m jaxnav.train`` and ``python -m jaxnav.evaluate``.

Bad input of any kind is one line on stderr naming the value, exit code 2, nothing written.
Training exit codes: 0 done, 2 bad input, 3 diverged (NaN/Inf; the last good checkpoint is
kept), 128 + signal number when stopped by SIGINT (130) or SIGTERM (143) after saving a
checkpoint. An unfinished run lives in the hidden sibling ``.NAME.partial`` of its ``--out``
and continues with ``--resume OUT``; it is renamed to ``OUT`` when complete.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils

from jaxnav import programs, run_dir, sharding
from jaxnav.agents import dqn
from jaxnav.checkpoints import Checkpoints
from jaxnav.config import MAX_STEPS, TrainConfig
from jaxnav.evaluate import evaluate_seeds, mean_of, seed_statistics
from jaxnav.presets import train_defaults
from jaxnav.registration import registered_envs
from jaxnav.train import DIVERGENCE_QUANTITIES, METRIC_NAMES, Trainer

EXIT_DIVERGED = 3
CHECKPOINT_FLAGS = ("checkpoint_every", "keep_checkpoints")  # kept by --resume unless given

HELP = {
    "env": f"environment id ({', '.join(registered_envs())})",
    "seed": "first seed; seeds are seed .. seed+num_seeds-1",
    "num_seeds": "seeds trained at once (vmapped in one program)",
    "total_timesteps": "env steps per seed",
    "num_envs": "parallel environments per seed",
    "devices": "devices to shard over, a count or 'all' (of every host): seeds are split "
    "first, then each seed's envs, with gradients averaged across its devices",
    "hidden_sizes": "MLP widths, comma separated (the paper's: 512,256,128,64)",
    "dueling": "dueling heads V + A - mean(A) (paper eq. 7)",
    "double": "double-DQN targets (paper eq. 6)",
    "algo": "dqn (the paper's: replay and a target network) or pqn (lambda-returns over "
    "rollouts of many envs, no replay)",
    "layer_norm": "LayerNorm before each hidden ReLU (PQN's network)",
    "compute_dtype": "float32 or bfloat16 matrix products in the hidden layers",
    "rollout_length": "pqn: env steps of every env per iteration",
    "num_epochs": "pqn: passes over each rollout",
    "num_minibatches": "pqn: gradient steps per pass over a rollout",
    "td_lambda": "pqn: lambda of the lambda-returns",
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


SEED_STATISTICS = ("success_rate", "worst10_success")  # with IQM and intervals over seeds


class UsageError(Exception):
    """Bad command-line input: reported as one line, exit code 2."""


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, no usage dump
        raise UsageError(one_line(message))


def one_line(message: str) -> str:
    """An error quotes the user's text (a value, a path) verbatim; a line break in it must
    not split the error over lines."""
    return message.replace("\r", "\\r").replace("\n", "\\n")


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


def _devices(text: str) -> int | str:
    if text == "all":
        return text  # resolved to jax.device_count() once the backend (and hosts) are up
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"invalid device count {text!r} (a number or all)"
        ) from None


def parse_env_arg(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` to ``(key, value)``, the value as JSON where it parses, else a string."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"invalid override {text!r} (use KEY=VALUE)")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value  # a bare string, e.g. obs_mode=paper


def add_env_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--env-arg",
        type=parse_env_arg,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="environment override, repeatable (e.g. size=11, obs_mode=paper)",
    )
    p.add_argument(
        "--maze-file",
        type=Path,
        metavar="PATH",
        help="your own maze as a text file (README: Mazes); the env id defaults to RobotMaze-v0",
    )


def env_from_args(args: argparse.Namespace, env: str | None) -> tuple[str | None, dict[str, Any]]:
    """``(env id, env overrides)`` from ``--env-arg`` and ``--maze-file`` (which implies
    RobotMaze-v0 unless an id is given)."""
    env_kwargs = dict(args.env_arg or [])
    if getattr(args, "maze_file", None) is not None:
        env_kwargs["maze_file"] = str(args.maze_file)
        env = env or "RobotMaze-v0"
    return env, env_kwargs


class _DefaultsShown(argparse.ArgumentDefaultsHelpFormatter):
    """Shows defaults, except None ones (training flags spell out their env-dependent default)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None:
            return action.help
        return super()._get_help_string(action)


def train_parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="python -m jaxnav.train",
        description="Train a (dueling, double) DQN or a PQN; all seeds and the whole run are one "
        "program.",
        formatter_class=_DefaultsShown,
    )
    defaults = TrainConfig()
    env_defaults = {
        "robot envs": train_defaults("RobotSimple-v0"),
        "--algo pqn": train_defaults("GridMaze-v0", "pqn"),
        "--algo pqn on robot envs": train_defaults("RobotSimple-v0", "pqn"),
        "--algo pqn on RobotNav-v0": train_defaults("RobotNav-v0", "pqn"),
        "GridMaze-Random-v0": train_defaults("GridMaze-Random-v0"),  # its default: pqn
    }
    for f in dataclasses.fields(TrainConfig):
        if f.name == "env_kwargs":
            continue
        default = getattr(defaults, f.name)
        flag = "--" + f.name.replace("_", "-")
        if isinstance(default, bool):
            kind, meta = _bool, "{true,false}"
        elif isinstance(default, tuple):
            kind, meta, default = _int_list, "W,W,...", ",".join(map(str, default))
        elif f.name == "devices":
            kind, meta = _devices, "{N,all}"
        else:
            kind, meta = type(default), None
        shown = f"default: {default}" + "".join(
            f"; {env}: {tuned[f.name]}" for env, tuned in env_defaults.items() if f.name in tuned
        )
        # None = not given: the env's tuned default (TrainConfig.for_env) fills it in
        help_text = f"{HELP[f.name]} ({shown})" if f.name in HELP else f"({shown})"
        p.add_argument(flag, type=kind, default=None, metavar=meta, help=help_text)
    add_env_args(p)
    p.add_argument("--out", type=Path, help="run directory (default: runs/<env>-<time>)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument(
        "--resume",
        type=Path,
        metavar="OUT",
        help="continue the unfinished run OUT from its latest checkpoint (bitwise the same "
        "result); other training flags must be left out or match the run's",
    )
    p.add_argument(
        "--checkpoint-every",
        type=int,
        default=80_000,
        metavar="STEPS",
        help="env steps between checkpoints of the full training state (rounded to logging "
        "intervals; one is also saved at the end and on SIGINT/SIGTERM)",
    )
    p.add_argument(
        "--keep-checkpoints", type=int, default=2, metavar="K", help="newest checkpoints kept"
    )
    hosts = p.add_argument_group(
        "several hosts (README: Several devices and hosts); run the same command on every "
        "host with its own --process-id, an --out all of them can read, and --devices all"
    )
    hosts.add_argument("--coordinator", metavar="HOST:PORT", help="process 0's address")
    hosts.add_argument("--num-processes", type=int, metavar="N", help="processes in the run")
    hosts.add_argument("--process-id", type=int, metavar="I", help="this process, 0 .. N-1")
    return p


def start_hosts(args: argparse.Namespace) -> None:
    """``jax.distributed.initialize`` when ``--coordinator`` is given (before anything else
    touches the JAX backend); ``UsageError`` for an incomplete or impossible set of flags."""
    flags = {"--coordinator": args.coordinator, "--num-processes": args.num_processes}
    flags["--process-id"] = args.process_id
    if all(v is None for v in flags.values()):
        return
    missing = [k for k, v in flags.items() if v is None]
    if missing:
        raise UsageError(f"{', '.join(missing)} missing: the three host flags go together")
    if not 1 <= args.num_processes <= 4096:
        raise UsageError(f"--num-processes {args.num_processes}: must be in [1, 4096]")
    if not 0 <= args.process_id < args.num_processes:
        raise UsageError(
            f"--process-id {args.process_id}: must be in [0, {args.num_processes - 1}]"
        )
    if args.resume is None and args.out is None:
        raise UsageError("--out is needed with several processes: all of them write one run")
    host, _, port = args.coordinator.rpartition(":")
    if not host or not port.isdigit():
        raise UsageError(f"--coordinator {args.coordinator!r}: use HOST:PORT")
    try:
        jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    except Exception as e:  # noqa: BLE001 (XLA raises several kinds for an unreachable peer)
        raise ValueError(f"--coordinator {args.coordinator}: {str(e).splitlines()[0]}") from None


def is_primary() -> bool:
    """Process 0 of a run over several hosts (and the only process otherwise) writes the
    run directory and prints progress."""
    return jax.process_index() == 0


def print_primary(*args: Any, **kwargs: Any) -> None:
    if is_primary():
        print(*args, **kwargs)


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """The flags given (not None) over the env's tuned defaults over TrainConfig's."""
    values = {}
    for f in dataclasses.fields(TrainConfig):
        v = getattr(args, f.name, None)
        if f.name != "env_kwargs" and v is not None:
            values[f.name] = _int_list(v) if f.name == "hidden_sizes" and isinstance(v, str) else v
    if values.get("devices") == "all":
        values["devices"] = jax.device_count()
    env, values["env_kwargs"] = env_from_args(args, values.pop("env", None))
    return TrainConfig.for_env(env or "GridMaze-v0", **values)


class Progress:
    """Progress lines, one per logging interval, printed between the compiled intervals."""

    def __init__(self, config: TrainConfig, quiet: bool):
        self.config, self.quiet = config, quiet
        self.seconds: dict[int, float] = {}  # wall time of each interval, by its env steps
        self.restart(0)

    def restart(self, start_steps: int) -> float:
        """Start timing (at ``start_steps`` env steps, when resumed); returns the time."""
        self.start = self.last = time.perf_counter()
        self.start_steps = start_steps
        return self.start

    def __call__(self, metrics: dict[str, np.ndarray]) -> None:
        """``metrics`` of one logging interval, every seed (leading axis)."""
        steps = int(np.ravel(metrics["env_steps"])[0])
        now = time.perf_counter()
        self.seconds[steps], self.last = now - self.last, now
        if self.quiet:
            return
        elapsed = now - self.start
        total = self.config.num_logs * self.config.steps_per_log
        sps = (steps - self.start_steps) * self.config.num_seeds / max(elapsed, 1e-9)
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
        """Env steps/s (all seeds) of each logging interval (NaN where not timed)."""
        dt = np.array([self.seconds.get(int(s), np.nan) for s in env_steps])
        interval = self.config.steps_per_log * self.config.num_seeds
        return interval / dt


def enable_compilation_cache() -> None:
    """Persist compiled programs across runs (``JAXNAV_CACHE_DIR``, default
    ``~/.cache/jaxnav/xla``; set it to an empty string to disable): a second run of the same
    config skips XLA compilation."""
    path = os.environ.get("JAXNAV_CACHE_DIR", str(Path.home() / ".cache" / "jaxnav" / "xla"))
    if path:
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def fail(prog: str, message: str) -> int:
    print(f"{prog}: error: {one_line(message)}", file=sys.stderr)
    return 2


class Diverged(Exception):
    """A seed's loss, Q-values or parameters became NaN or Inf (see ``TrainState.diverged``)."""


class Interrupted(Exception):
    """Stopped by a signal after saving a checkpoint; ``args``: (env step reached, signal)."""


@dataclasses.dataclass
class Saving:
    """Checkpointing of a run being written to ``directory``: the full training state every
    ``every`` logging intervals (and at the end) into ``directory/checkpoints``, the newest
    ``keep`` kept, with metrics.csv so far beside them. ``signals`` is filled by the signal
    handler: the run saves and stops after the current interval."""

    directory: Path
    every: int
    keep: int
    signals: list[int] = dataclasses.field(default_factory=list)


def train_seeds(
    trainer: Trainer, keys: jax.Array, progress: Progress, saving: Saving | None = None
) -> tuple[Any, dict[str, np.ndarray], float, float]:
    """Train every seed of ``keys`` at once; ``(final state, metrics [seeds, logs], compile
    seconds, train seconds)``, with a progress line per logging interval.

    One compiled logging interval, called once per interval, with progress printed in
    between: a host callback inside the program would keep XLA's persistent cache from
    storing it (JAX does not cache programs with host callbacks). With ``saving``, the run
    starts from the newest checkpoint there if any (the result is bitwise the same as an
    uninterrupted run), raises ``Diverged`` at the end of an interval in which a seed
    diverged (before saving it, so the newest checkpoint is a good one) and ``Interrupted``
    after saving when a signal came.
    """
    t0 = time.perf_counter()
    compiled = programs.compile_training(trainer, keys, programs.cache_directory())
    init, interval, state_like = compiled.init, compiled.interval, compiled.state_like
    compile_s = time.perf_counter() - t0
    cached = " (traced programs from the cache)" if compiled.from_cache else ""
    print_primary(f"compiled in {compile_s:.1f}s{cached}", flush=True)
    c = trainer.config
    steps_per_log = c.steps_per_log
    like = compiled.metrics_like
    metrics = {k: np.zeros((len(keys), c.num_logs), like[k].dtype) for k in METRIC_NAMES}
    checkpoints = (  # every process restores; process 0 alone saves
        None
        if saving is None
        else Checkpoints(saving.directory / "checkpoints", saving.keep, writer=is_primary())
    )
    done = 0 if checkpoints is None else checkpoints.latest() or 0
    if done:
        try:
            done, state, metrics, meta = checkpoints.restore(state_like, metrics)
            state = sharding.place(state, trainer.mesh, sharding.state_specs(state_like))
        except Exception as e:  # orbax raises many kinds for a damaged or foreign checkpoint
            msg = f"{checkpoints.directory}: cannot restore checkpoint {done}: {e}"
            raise ValueError(msg.splitlines()[0]) from None
        progress.seconds.update({int(k): v for k, v in meta["seconds"].items()})
        print_primary(
            f"resumed from the checkpoint at env step {done * steps_per_log:,}", flush=True
        )
    else:
        state = init(keys)
    t0 = progress.restart(done * steps_per_log)
    for log in range(done, c.num_logs):
        state, chunk = interval(state, np.int32(log))
        chunk = jax.device_get(chunk)  # [seeds, 1] each
        for k in METRIC_NAMES:
            metrics[k][:, log] = chunk[k][:, 0]
        progress(chunk)
        if saving is None:
            continue
        _raise_if_diverged(state, c, checkpoints)
        end = log + 1 == c.num_logs
        stop = _signal_on_any_host(saving.signals)  # all processes stop after the same interval
        if (log + 1) % saving.every == 0 or end or stop:
            host_state = sharding.to_host(state)
            if is_primary():
                seconds = {str(k): v for k, v in progress.seconds.items()}
                checkpoints.save(log + 1, host_state, metrics, {"seconds": seconds})
                so_far = {k: v[:, : log + 1] for k, v in metrics.items()}
                path = saving.directory / "metrics.csv"
                run_dir.write_metrics_csv(path, so_far, run_dir.seeds_of(c))
        if stop and not end:
            checkpoints.close()
            raise Interrupted((log + 1) * steps_per_log, stop)
    train_s = time.perf_counter() - t0
    if checkpoints is not None:
        checkpoints.close()
    return state, metrics, compile_s, train_s


def _signal_on_any_host(received: list[int]) -> int:
    """The first signal this process received, or one another process received; 0 if none."""
    first = received[0] if received else 0
    if jax.process_count() == 1:
        return first
    return int(multihost_utils.process_allgather(np.int32(first)).max())


def _raise_if_diverged(state: Any, c: TrainConfig, checkpoints: Checkpoints) -> None:
    codes, at = sharding.to_host((state.diverged, state.diverged_at))
    if not codes.any():
        return
    last_good = (checkpoints.latest() or 0) * c.steps_per_log
    bad = [
        f"seed {seed}: {DIVERGENCE_QUANTITIES[code - 1]} became NaN or Inf at env step {a:,}"
        for seed, code, a in zip(run_dir.seeds_of(c), codes, at, strict=True)
        if code
    ]
    kept = (
        "no checkpoint was saved before it"
        if not last_good
        else f"the last good checkpoint (env step {last_good:,}) is kept in {checkpoints.directory}"
    )
    checkpoints.close()
    raise Diverged(f"{'; '.join(bad)}; {kept}")


def prepare_training(
    argv: list[str],
) -> tuple[argparse.Namespace, TrainConfig, Path, Path, Trainer]:
    """``(args, config, out, partial, trainer)``: every check ``train_main`` makes before it
    writes or compiles anything; ``UsageError`` or ``ValueError`` (one line) on bad input."""
    try:
        return _prepare_training(argv)
    except ValueError as e:
        raise ValueError(one_line(str(e))) from None


def _prepare_training(
    argv: list[str],
) -> tuple[argparse.Namespace, TrainConfig, Path, Path, Trainer]:
    args = train_parser().parse_args(argv)
    start_hosts(args)
    if args.resume is not None:
        out, partial, config = resumable_run(args, argv)
    else:
        config = config_from_args(args)
        config.validate()
        out = args.out or Path("runs") / f"{config.env}-{time.strftime('%Y%m%d-%H%M%S')}"
        partial = run_dir.partial_dir(out)
        if is_primary():
            run_dir.check_writable(out)
    if not 1 <= args.checkpoint_every <= MAX_STEPS:
        raise ValueError(f"--checkpoint-every {args.checkpoint_every}: must be in [1, {MAX_STEPS}]")
    if not 1 <= args.keep_checkpoints <= 1000:
        raise ValueError(f"--keep-checkpoints {args.keep_checkpoints}: must be in [1, 1000]")
    return args, config, out, partial, Trainer(config)


def train_main(argv: Sequence[str] | None = None) -> int:
    prog = "jaxnav.train"
    t_start = time.perf_counter()
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        args, config, out, partial, trainer = prepare_training(argv)
    except (UsageError, ValueError) as e:
        return fail(prog, str(e))
    progress = Progress(config, args.quiet or not is_primary())

    enable_compilation_cache()
    steps_per_log = config.steps_per_log
    every = max(1, round(args.checkpoint_every / steps_per_log))
    saving = Saving(partial, every, args.keep_checkpoints)
    if args.resume is None and is_primary():
        partial.mkdir(parents=True)
        document = run_dir.config_document(config, trainer)
        document["checkpointing"] = {k: getattr(args, k) for k in CHECKPOINT_FLAGS}
        run_dir.write_json(partial / "config.json", document)
    if jax.process_count() > 1:
        multihost_utils.sync_global_devices("jaxnav: run directory created")
    resume = f"python -m jaxnav.train --resume {out}"
    print_primary(
        f"training {config.env} for {config.total_timesteps:,} steps x {config.num_seeds} "
        f"seed(s), {config.num_envs} envs each on {config.devices} device(s) -> {out}\n"
        f"checkpoint every {every * steps_per_log:,} env steps in {partial}; "
        f"if stopped, continue with: {resume}",
        flush=True,
    )
    restore_signal_handlers = _stop_on_signals(saving.signals)
    try:
        try:
            state, metrics, compile_s, train_s = train_seeds(
                trainer, run_dir.seed_keys(config), progress, saving
            )
        except Interrupted as e:
            steps, signum = e.args  # signum: another host's, when this one got none
            name = signal.Signals(signum).name
            print(
                f"{prog}: stopped by {name} at env step {steps:,} (checkpoint saved); "
                f"continue with: {resume}",
                file=sys.stderr,
            )
            return 128 + signum
        except Diverged as e:
            print(f"{prog}: diverged: {e}", file=sys.stderr)
            return EXIT_DIVERGED
        except ValueError as e:  # a checkpoint that does not restore
            return fail(prog, str(e))
        # a signal from here on is let be: the trained run is complete in seconds
        params = sharding.to_host(state.params)
        if is_primary():
            times = (compile_s, train_s, t_start)
            finish_run(trainer, params, metrics, progress, partial, out, times)
    finally:
        restore_signal_handlers()
    return 0


def finish_run(
    trainer: Trainer,
    params: Any,
    metrics: dict[str, np.ndarray],
    progress: Progress,
    partial: Path,
    out: Path,
    times: tuple[float, float, float],
) -> None:
    """Evaluate the trained seeds, complete the run in ``partial`` and rename it to ``out``;
    ``times`` are the compile and train seconds and the run's start (``perf_counter``)."""
    config = trainer.config
    compile_s, train_s, t_start = times
    # wall-clock timing apart from metrics.csv, which is bitwise reproducible
    sps = progress.steps_per_second(metrics["env_steps"][0])
    shape = metrics["env_steps"].shape
    timing = {"env_steps": metrics["env_steps"], "sps": np.broadcast_to(sps, shape)}
    t0 = time.perf_counter()
    trained = evaluate_seeds(trainer, params, config.eval_episodes, seed=10_000)
    rand = evaluate_seeds(trainer, params, config.eval_episodes, 10_000, "random")
    eval_s = time.perf_counter() - t0

    # complete the hidden sibling, then rename: a crash never leaves half a run at ``out``
    seeds = run_dir.seeds_of(config)
    run_dir.write_metrics_csv(partial / "metrics.csv", metrics, seeds)
    run_dir.write_metrics_csv(partial / "timing.csv", timing, seeds)
    run_dir.save_params(partial, params)
    summary = {
        "env": config.env,
        "seeds": seeds,
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
    shutil.rmtree(out / "checkpoints")  # the run is complete: its final state is params/
    print_eval_table(
        config.env, {"trained (greedy)": summary["trained"], "random": summary["random_policy"]}
    )
    print(
        f"compile {compile_s:.1f}s, train {train_s:.1f}s, eval {eval_s:.1f}s, "
        f"total {summary['wall_s']:.1f}s; run saved to {out}"
    )


def resumable_run(args: argparse.Namespace, argv: list[str]) -> tuple[Path, Path, TrainConfig]:
    """``(out, partial, config)`` of the unfinished run ``--resume`` names; ``ValueError``
    if there is none or a training flag given now differs from the run's config."""
    out, partial = run_dir.find_unfinished(args.resume)
    if args.out is not None:
        raise ValueError(f"--out {args.out}: --resume continues the run in place; leave --out out")
    saved = run_dir.load_config(partial)
    # flags given on this command line (argparse keeps values already in the namespace)
    given = vars(train_parser().parse_args(argv, argparse.Namespace(**dict.fromkeys(vars(args)))))
    given = {k: v for k, v in given.items() if v is not None}
    saved_flags = json.loads((partial / "config.json").read_text()).get("checkpointing", {})
    for name in CHECKPOINT_FLAGS:
        setattr(args, name, given.get(name, saved_flags.get(name, getattr(args, name))))
    asked = config_from_args(argparse.Namespace(**{**vars(args), **_as_args(saved), **given}))
    differ = [
        f.name
        for f in dataclasses.fields(TrainConfig)
        if getattr(asked, f.name) != getattr(saved, f.name)
    ]
    if differ:
        was = ", ".join(f"{n}={getattr(saved, n)!r}" for n in differ)
        now = ", ".join(f"{n}={getattr(asked, n)!r}" for n in differ)
        raise ValueError(
            f"--resume {args.resume}: the run was started with {was}, not {now}; "
            "leave these flags out to resume it"
        )
    return out, partial, saved


def _as_args(config: TrainConfig) -> dict[str, Any]:
    """``config`` as the namespace values of ``train_parser`` (its inverse is config_from_args)."""
    values = {f.name: getattr(config, f.name) for f in dataclasses.fields(TrainConfig)}
    values["env_arg"] = list(values.pop("env_kwargs").items())
    return values


def _stop_on_signals(received: list[int]) -> Callable[[], None]:
    """SIGINT/SIGTERM append to ``received`` (the training loop saves and stops); a second
    one ends the process at once, as the default would. Returns a function restoring the
    previous handlers. No-op outside the main thread (Python only signals that one)."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def handler(signum: int, frame: Any) -> None:
        if received:  # asked twice: stop now, the last checkpoint stays
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
        received.append(signum)
        print(
            f"\n{signal.Signals(signum).name}: saving a checkpoint after this logging "
            "interval, then stopping (again to stop without saving)",
            file=sys.stderr,
            flush=True,
        )

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}

    def restore() -> None:
        for s, h in previous.items():
            signal.signal(s, h)

    return restore


EVAL_COLUMNS = (
    "success_rate",
    "collision_rate",
    "timeout_rate",
    "worst10_success",
    "mean_return",
    "mean_steps",
    "mean_path_ratio",
)


def format_value(value: float | None, digits: int = 3) -> str:
    """A table cell: ``n/a`` for a value not measured (None or NaN)."""
    if value is None or value != value:
        return "n/a"
    return f"{value:.{digits}f}"


def print_eval_table(env: str, rows: dict[str, dict[str, float | None]]) -> None:
    """Means over seeds per policy; ``worst10_success`` is the mean success of the 10% of
    mazes with the lowest success (``evaluate.worst_fraction_mean``)."""
    first = next(iter(rows.values()))
    mazes = first.get("mazes")
    per = f" over {mazes:.0f} mazes" if mazes is not None and mazes > 1 else ""
    print(f"\n{env}: {first['episodes']:.0f} episodes per policy{per}")
    print("| policy | " + " | ".join(EVAL_COLUMNS) + " |")
    print("|---" * (len(EVAL_COLUMNS) + 1) + "|")
    for name, r in rows.items():
        print(f"| {name} | " + " | ".join(format_value(r.get(c)) for c in EVAL_COLUMNS) + " |")


def format_interval(stat: dict[str, Any], key: str) -> str:
    """``0.912 [0.880, 0.940]`` from ``evaluate.seed_statistics``'s ``key`` and ``key_ci95``."""
    ci = stat[f"{key}_ci95"]
    tail = "" if ci is None else f" [{ci[0]:.3f}, {ci[1]:.3f}]"
    return format_value(stat[key]) + tail


def print_seed_statistics(stats: dict[str, dict[str, Any]]) -> None:
    """Per metric over seeds: mean and IQM with 95% bootstrap intervals, and the seed count."""
    for metric, st in stats.items():
        print(
            f"{metric} over {st['seeds']} seeds: mean {format_interval(st, 'mean')}, "
            f"IQM {format_interval(st, 'iqm')} (95% bootstrap intervals)"
        )


def evaluate_parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="python -m jaxnav.evaluate",
        description="Evaluate a trained run (greedy) or the random agent on fresh episodes.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("run", type=Path, help="run directory written by jaxnav.train")
    p.add_argument("--env", help="evaluate on another env id (generalization); default: the run's")
    add_env_args(p)
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0, help="seed of the test episodes")
    p.add_argument("--policy", choices=("trained", "random"), default="trained")
    p.add_argument("--out", type=Path, help="output JSON (default: RUN/eval.json)")
    return p


def load_run_on(
    run: Path, env: str, env_kwargs: dict[str, Any]
) -> tuple[TrainConfig, Trainer, Any]:
    """``(config, trainer, params)`` of the trained run directory ``run`` set up on ``env``
    with exactly ``env_kwargs``; ``ValueError`` (or ``FileNotFoundError``) where the run or the
    env is bad or the env's observations do not fit the run's network."""
    config = run_dir.load_config(run)
    config = dataclasses.replace(config, env=env, env_kwargs=dict(env_kwargs))
    config.validate()
    trainer = Trainer(config)
    network = run_dir.load_network(run)
    onehot = network.get("onehot_sizes")  # runs before it was saved had none
    want = (network["obs_size"], None if onehot is None else tuple(onehot))
    dqn.check_input_fits(config.env, trainer.network_input, want)
    return config, trainer, run_dir.load_trained_params(run, trainer)


def evaluate_main(argv: Sequence[str] | None = None) -> int:
    prog = "jaxnav.evaluate"
    try:
        args = evaluate_parser().parse_args(argv)
        if not 1 <= args.episodes <= 10**7:
            raise ValueError(f"--episodes {args.episodes}: must be in [1, 10000000]")
        if args.seed < 0:
            raise ValueError(f"--seed {args.seed}: must be non-negative")
        env, overrides = env_from_args(args, args.env)
        config = run_dir.load_config(args.run)
        env_kwargs = {**(config.env_kwargs if env is None else {}), **overrides}
        out = args.out or args.run / "eval.json"
        if not out.parent.is_dir():
            raise ValueError(f"--out {out}: directory {out.parent} does not exist")
        config, trainer, params = load_run_on(args.run, env or config.env, env_kwargs)
    except (UsageError, ValueError, FileNotFoundError) as e:
        return fail(prog, str(e))
    enable_compilation_cache()
    rows = evaluate_seeds(trainer, params, args.episodes, args.seed, args.policy, per_maze=True)
    mazes = trainer.env.num_layouts(trainer.env_params)
    stats = {m: seed_statistics([r[m] for r in rows]) for m in SEED_STATISTICS}
    result = {
        "run": str(args.run),
        "env": config.env,
        "env_kwargs": config.env_kwargs,
        "policy": args.policy,
        "episodes": args.episodes,
        "seed": args.seed,
        "episodes_per_maze": args.episodes / mazes,
        **mean_of(rows),
        "over_seeds": stats,
        "per_seed": rows,
    }
    run_dir.write_json(out, result)
    print_eval_table(config.env, {args.policy: mean_of(rows)})
    if args.episodes % mazes:
        print(
            f"note: {args.episodes} episodes over {mazes} mazes: round-robin, "
            f"{args.episodes // mazes} or {args.episodes // mazes + 1} per maze"
        )
    if len(rows) > 1:
        print_seed_statistics(stats)
    print(f"wrote {out}")
    return 0
