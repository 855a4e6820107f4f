"""``python -m jaxnav.train``: parse the training flags, then train through ``jaxnav.runner``.

Bad input of any kind is one line on stderr naming the value, exit code 2, nothing written.
Exit codes: 0 done, 2 bad input, 3 diverged (NaN/Inf; the last good checkpoint is kept),
4 no space left on device or another write the machine refused, e.g. ``--resume`` of a run
whose directory is read-only (the last good checkpoint is kept), 128 + signal number when
stopped by SIGINT (130) or SIGTERM (143) after saving a checkpoint.
An unfinished run lives in the hidden sibling ``.NAME.partial`` of its ``--out`` and continues
with ``--resume OUT``; it is renamed to ``OUT`` when complete.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import shlex
import shutil
import signal
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import jax

from jaxnav import loggers, raise_stopped, run_dir, runner, sharding
from jaxnav.cli import (
    Parser,
    UsageError,
    add_env_args,
    env_from_args,
    fail,
    one_line,
    parse_bool,
    write_failed,
)
from jaxnav.config import MAX_STEPS, TrainConfig
from jaxnav.programs import enable_compilation_cache
from jaxnav.safe_io import WRITE_FAULTS, WriteFault, write_fault_errno
from jaxnav.train import Trainer

EXIT_DIVERGED = 3
EXIT_DISK_FULL = runner.EXIT_DISK_FULL
CHECKPOINT_FLAGS = ("checkpoint_every", "keep_checkpoints")  # kept by --resume unless given
CHECKPOINT_EVERY = 80_000  # env steps, rounded to the run's logging intervals


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


def preset_defaults(argv: Sequence[str] | None) -> TrainConfig:
    """The defaults ``--help`` shows: the preset of the ``--env`` and ``--algo`` in ``argv``
    (``TrainConfig.for_env``), the paper's grid DQN without them or where they are not valid
    (parsing the real flags then names the bad one)."""
    pre = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    pre.add_argument("--env", default="GridMaze-v0")
    pre.add_argument("--algo")
    try:
        known, _ = pre.parse_known_args(list(sys.argv[1:] if argv is None else argv))
        algo = {} if known.algo is None else {"algo": known.algo}
        return TrainConfig.for_env(known.env, **algo)
    except (argparse.ArgumentError, SystemExit, ValueError, TypeError):
        return TrainConfig()


def parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The flags; ``--help`` shows each default once, the preset's for the ``--env`` and
    ``--algo`` in ``argv`` (``python -m jaxnav.train --env RobotNav-v0 --algo pqn --help``)."""
    defaults = preset_defaults(argv)
    p = Parser(
        prog="python -m jaxnav.train",
        description="Train a (dueling, double) DQN, a PQN or a PPO policy; all seeds and the "
        f"whole run are one program. Defaults shown: {defaults.env} with --algo "
        f"{defaults.algo} (its preset, jaxnav.presets); add --env and --algo to --help for "
        "another's.",
    )
    for f in dataclasses.fields(TrainConfig):
        if f.name == "env_kwargs":
            continue
        default = getattr(defaults, f.name)
        flag = "--" + f.name.replace("_", "-")
        # the flag's type is the declared default's (a preset's 1 would make --lr 0.5 refused)
        if isinstance(f.default, bool):
            kind, meta = parse_bool, "{true,false}"
        elif isinstance(f.default, tuple):
            kind, meta, default = _int_list, "W,W,...", ",".join(map(str, default))
        elif f.name == "devices":
            kind, meta = _devices, "{N,all}"
        else:
            kind, meta = type(f.default), None
        # None = not given: the env's tuned default (TrainConfig.for_env) fills it in
        help_text = f"{f.metadata['help']} (default: {default})"
        p.add_argument(flag, type=kind, default=None, metavar=meta, help=help_text)
    add_env_args(p)
    p.add_argument("--out", type=Path, help="run directory (default: runs/<env>-<time>)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument(
        "--tensorboard",
        action="store_true",
        help="also write the metrics as TensorBoard event files to OUT/tensorboard "
        '(tensorboard --logdir OUT; needs pip install -e ".[tensorboard]")',
    )
    p.add_argument(
        "--wandb",
        action="store_true",
        help="also log the metrics to Weights & Biases (needs wandb)",
    )
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
        metavar="STEPS",
        help="env steps between checkpoints of the full training state (rounded to logging "
        "intervals; one is also saved at the end and on SIGINT/SIGTERM) (default: "
        f"{CHECKPOINT_EVERY})",
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
    """Start a run over several processes when ``--coordinator`` is given (before anything
    else touches the JAX backend); ``UsageError`` for an incomplete or impossible set of flags."""
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
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise UsageError(f"--coordinator {args.coordinator!r}: use HOST:PORT, PORT in [1, 65535]")
    runner.start_hosts(args.coordinator, args.num_processes, args.process_id)


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


def prepare_training(
    argv: list[str],
) -> tuple[argparse.Namespace, TrainConfig, Path, Path, list[str], Trainer]:
    """``(args, config, out, partial, notes, trainer)``: every check ``main`` makes before it
    writes or compiles anything; ``UsageError`` or ``ValueError`` (one line) on bad input.
    Step counts that are not whole logging intervals are rounded (``config.total_timesteps``
    up, ``args.checkpoint_every`` to the nearest), each rounding a line of ``notes``."""
    try:
        return _prepare_training(argv)
    except ValueError as e:
        raise ValueError(one_line(str(e))) from None


def _prepare_training(
    argv: list[str],
) -> tuple[argparse.Namespace, TrainConfig, Path, Path, list[str], Trainer]:
    args = parser(argv).parse_args(argv)
    if args.tensorboard:  # asked for but not installed: say so before anything is written
        loggers.require("tensorboardX", "--tensorboard")
    if args.wandb:
        loggers.require("wandb", "--wandb")
    start_hosts(args)
    notes = []
    if args.resume is not None:
        out, partial, config = resumable_run(args, argv)
    else:
        config = config_from_args(args)
        config.validate()
        config, note = config.whole_intervals()  # the steps trained, as config.json records
        notes.append(note)
        out = args.out or Path("runs") / f"{config.env}-{time.strftime('%Y%m%d-%H%M%S')}"
        partial = run_dir.partial_dir(out)
        if runner.is_primary():
            run_dir.check_writable(out)
    asked_every = args.checkpoint_every
    if args.checkpoint_every is None:
        args.checkpoint_every = CHECKPOINT_EVERY
    if not 1 <= args.checkpoint_every <= MAX_STEPS:
        raise ValueError(f"--checkpoint-every {args.checkpoint_every}: must be in [1, {MAX_STEPS}]")
    if not 1 <= args.keep_checkpoints <= 1000:
        raise ValueError(f"--keep-checkpoints {args.keep_checkpoints}: must be in [1, 1000]")
    per_log = config.steps_per_log
    every = max(1, round(args.checkpoint_every / per_log)) * per_log
    if every != args.checkpoint_every and asked_every is not None:
        notes.append(
            f"--checkpoint-every {args.checkpoint_every} rounded to {every} "
            f"({every // per_log} logging interval{'s' if every > per_log else ''} of "
            f"{per_log} env steps)"
        )
    args.checkpoint_every = every  # the run's checkpointing records the steps it keeps
    trainer = Trainer(config)
    if args.resume is None:
        trainer.init_params  # noqa: B018 (init_from's policy is checked before anything is written)
    return args, config, out, partial, [n for n in notes if n], trainer


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def main(argv: Sequence[str] | None = None) -> int:
    """Train as the flags in ``argv`` (default: the command line's) say; the exit code."""
    locks: list[run_dir.RunLock] = []
    run: list[tuple[Path, bool]] = []  # the run's out once known, and whether it is new
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:
        # SIGINT or SIGTERM before training is answered below; training's own handler takes
        # over around the training loop
        previous = {s: signal.signal(s, raise_stopped) for s in STOP_SIGNALS}
    try:
        return _main(argv, locks, run)
    except KeyboardInterrupt as e:
        for lock in locks:
            lock.release()
        out, new = run[0] if run else (None, False)
        return stopped_early(out, new and bool(locks), getattr(e, "signum", signal.SIGINT))
    finally:  # the OS drops it when the process ends; a caller in-process may go on
        for lock in locks:
            lock.release()
        if main_thread:
            for s, handler in previous.items():
                if handler is not None:  # None: a handler not set from Python
                    signal.signal(s, handler)


def stopped_early(out: Path | None, created: bool, signum: int = signal.SIGINT) -> int:
    """Report a SIGINT or SIGTERM before training began in one line, exit code 128 + it: how
    to continue a run whose config.json is written; else a run directory this process
    ``created`` holds nothing and goes."""
    partial = None if out is None else run_dir.partial_dir(out)
    if partial is not None and (partial / "config.json").is_file():
        how = f"continue with: python -m jaxnav.train --resume {shlex.quote(str(out))}"
    else:
        if created and partial is not None:
            shutil.rmtree(partial, ignore_errors=True)  # only its lock file: nothing to keep
        how = "nothing was trained or written"
    name = signal.Signals(signum).name
    print(f"jaxnav.train: stopped by {name} before training began; {how}", file=sys.stderr)
    return 128 + signum


def _main(
    argv: Sequence[str] | None, locks: list[run_dir.RunLock], run: list[tuple[Path, bool]]
) -> int:
    """``main``, holding the run's lock (put in ``locks``) from before anything is written;
    ``(out, new run)`` in ``run`` once known."""
    prog = "jaxnav.train"
    t_start = time.perf_counter()
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        args, config, out, partial, notes, trainer = prepare_training(argv)
    except WriteFault as e:  # --out on a read-only or full disk
        return write_failed(prog, e)
    except (UsageError, ValueError) as e:
        return fail(prog, str(e))
    run.append((out, args.resume is None))
    for note in notes:
        runner.print_primary(note)
    resume = f"python -m jaxnav.train --resume {shlex.quote(str(out))}"
    try:  # held until the process ends: the OS drops an flock with its owner
        if runner.is_primary():
            locks.append(run_dir.lock_run(partial, new=args.resume is None))
        if locks and args.resume is not None and run_dir.is_finished(partial):
            run_dir.complete(partial, out)  # trained and written; only the rename was left
            print(f"run saved to {out}")
            return 0
    except ValueError as e:
        return fail(prog, str(e))
    except OSError as e:
        return write_refused(prog, e, resume)
    sinks: list[loggers.MetricsLogger] = []
    progress = runner.Progress(config, args.quiet or not runner.is_primary(), sinks)

    enable_compilation_cache()
    steps_per_log = config.steps_per_log
    every = args.checkpoint_every // steps_per_log  # whole intervals (prepare_training)
    saving = runner.Saving(partial, every, args.keep_checkpoints)
    checkpointing = {k: getattr(args, k) for k in CHECKPOINT_FLAGS}
    runner.open_run(trainer, partial, checkpointing if args.resume is None else None)
    if runner.is_primary():  # in the run directory, renamed with it when the run completes
        seeds = run_dir.seeds_of(config)
        if args.tensorboard:
            sinks.append(loggers.TensorBoardLogger(partial / "tensorboard", seeds))
        if args.wandb:
            document = run_dir.config_to_json(config)
            sinks.append(loggers.WandbLogger(out.name, document, partial, seeds))
    runner.print_primary(
        f"training {config.env} for {config.total_timesteps:,} steps x {config.num_seeds} "
        f"seed(s), {config.num_envs} envs each on {config.devices} device(s) -> {out}\n"
        f"a progress line every {steps_per_log:,} env steps (--log-interval), a checkpoint "
        f"every {every * steps_per_log:,} in {partial}; "
        f"if stopped, continue with: {resume}",
        flush=True,
    )
    with runner.stop_on_signals(saving.signals), quiet_write_faults():
        try:
            state, metrics, compile_s, train_s = runner.train_seeds(
                trainer, run_dir.seed_keys(config), progress, saving
            )
        except runner.Interrupted as e:
            return stopped(prog, e, resume)
        except runner.Diverged as e:
            print(f"{prog}: diverged: {e}", file=sys.stderr)
            return EXIT_DIVERGED
        except Exception as e:  # noqa: BLE001 (orbax wraps a full disk in several kinds)
            if runner.is_disk_full(e) or write_fault_errno(e) is not None:
                return write_refused(prog, e, resume)
            if isinstance(e, ValueError):  # a checkpoint that does not restore
                return fail(prog, str(e))
            raise
        finally:  # event files complete before the run directory is renamed
            for sink in sinks:
                sink.close()
        # a signal during the final evaluation stops it: --resume evaluates again
        params = sharding.to_host(state.params)
        if runner.is_primary():
            times = (compile_s, train_s, t_start)
            try:
                runner.finish_run(
                    trainer, params, metrics, progress, partial, out, times, saving.signals
                )
            except runner.Interrupted as e:
                return stopped(prog, e, resume)
            except ValueError as e:  # --out became something the run cannot be renamed to
                return fail(prog, str(e))
            except OSError as e:
                return write_refused(prog, e, resume)
    return 0


# what a third-party error about a refused write says (orbax logs them as text)
WRITE_FAULT_TEXT = (
    "No space left on device",
    "Disk quota exceeded",
    "Read-only file system",
    "Permission denied",
    "Input/output error",
)


class HoldWriteFaults(logging.Filter):
    """Holds back a log record about a write the machine refused: orbax logs a full disk, with
    tracebacks, before it raises it, and jaxnav reports it in one line (``write_refused``).
    The records held are in ``held``, shown after all when no write fault ends the run."""

    def __init__(self) -> None:
        super().__init__()
        self.held: list[logging.LogRecord] = []

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        text = record.getMessage()
        if (error is not None and (runner.is_disk_full(error) or write_fault_errno(error))) or any(
            fault in text for fault in WRITE_FAULT_TEXT
        ):
            self.held.append(record)
            return False
        return True


def is_closed_loop_error(error: BaseException | None) -> bool:
    """The error of a tensorstore write finishing after orbax's save failed and closed its
    event loop: a leftover of a refused write, reported (once, in one line) by jaxnav."""
    return isinstance(error, RuntimeError) and str(error) == "Event loop is closed"


def drop_closed_loop_errors() -> Any:
    """Make ``sys.unraisablehook`` (through which tensorstore reports its callbacks' errors)
    drop ``is_closed_loop_error`` errors, showing every other as before; returns the hook."""
    previous, closed_loop = sys.unraisablehook, is_closed_loop_error  # run as __main__, this
    # module's globals are gone when the interpreter ends, while tensorstore still reports

    def hook(unraisable: Any) -> None:
        if not closed_loop(unraisable.exc_value):
            previous(unraisable)

    sys.unraisablehook = hook
    return hook


@contextlib.contextmanager
def quiet_write_faults() -> Iterator[None]:
    """Within the block, orbax's (absl's) log records of a refused write are held back, and
    the closed-event-loop tracebacks tensorstore reports after it are dropped; every other
    record and error is shown as before. When ``write_refused`` reported a fault, the filter
    and hook stay (the leftover writes log and fail after the command's last line) and the
    held records are dropped; otherwise they are shown as they would have been."""
    absl_logger = logging.getLogger("absl")
    hold = HoldWriteFaults()
    absl_logger.addFilter(hold)
    previous = sys.unraisablehook
    hook = drop_closed_loop_errors()
    try:
        yield
    finally:
        if sys.unraisablehook is hook:  # no write fault reported: nothing is hidden
            absl_logger.removeFilter(hold)
            sys.unraisablehook = previous
            for record in hold.held:
                absl_logger.handle(record)


def write_refused(prog: str, error: Exception, resume: str) -> int:
    """Report a write the machine refused in one line with the command that continues the
    run, exit code 4: a full disk as ``runner.disk_full``, a read-only or forbidden run
    directory (``safe_io.WRITE_FAULTS``) naming the path; any other error is raised again."""
    code = write_fault_errno(error)
    if code is not None or runner.is_disk_full(error):
        drop_closed_loop_errors()  # for good: they come until the process ends
    if code is None or runner.is_disk_full(error):  # orbax's full disk is only text in its error
        return runner.disk_full(prog, error, resume)
    cause: BaseException | None = error
    for _ in range(20):  # the OSError that names the path, down a chain of causes
        if cause is None or getattr(cause, "filename", None) is not None:
            break
        cause = cause.__cause__ or cause.__context__
    where = getattr(cause, "filename", None) or "the run directory"
    print(
        f"{prog}: error: cannot write {where}: {WRITE_FAULTS[code]}; then continue with: {resume}",
        file=sys.stderr,
    )
    return EXIT_DISK_FULL


def stopped(prog: str, e: runner.Interrupted, resume: str) -> int:
    """Report a stop by a signal in one line; the exit code is 128 + the signal's number."""
    steps, signum = e.args  # signum: another host's, when this one got none
    name = signal.Signals(signum).name
    print(
        f"{prog}: stopped by {name} at env step {steps:,} (checkpoint saved); "
        f"continue with: {resume}",
        file=sys.stderr,
    )
    return 128 + signum


def resumable_run(args: argparse.Namespace, argv: list[str]) -> tuple[Path, Path, TrainConfig]:
    """``(out, partial, config)`` of the unfinished run ``--resume`` names; ``ValueError``
    if there is none or a training flag given now differs from the run's config."""
    out, partial = run_dir.find_unfinished(args.resume)
    run_dir.check_completable(out, "--resume")  # else it would train, then fail to rename
    if args.out is not None:
        raise ValueError(f"--out {args.out}: --resume continues the run in place; leave --out out")
    saved = run_dir.load_config(partial)
    # flags given on this command line (argparse keeps values already in the namespace)
    given = vars(parser().parse_args(argv, argparse.Namespace(**dict.fromkeys(vars(args)))))
    given = {k: v for k, v in given.items() if v is not None}
    saved_flags = run_dir.load_checkpointing(partial)
    for name in CHECKPOINT_FLAGS:
        setattr(args, name, given.get(name, saved_flags.get(name, getattr(args, name))))
    asked = config_from_args(argparse.Namespace(**{**vars(args), **_as_args(saved), **given}))
    # a run records the steps it trains: the asked count, rounded up as at the start, matches
    asked, whole = asked.whole_intervals()[0], saved.whole_intervals()[0]
    differ = [
        f.name
        for f in dataclasses.fields(TrainConfig)
        if getattr(asked, f.name) != getattr(whole, f.name)
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
    """``config`` as the namespace values of ``parser`` (its inverse is config_from_args)."""
    values = {f.name: getattr(config, f.name) for f in dataclasses.fields(TrainConfig)}
    values["env_arg"] = list(values.pop("env_kwargs").items())
    return values


if __name__ == "__main__":
    sys.exit(main())
