"""A training run on the host: the compiled logging intervals called one by one, with progress
lines, checkpoints, stopping on a signal and the divergence guard in between, then the run
finished (evaluated and written). ``python -m jaxnav.train`` and ``jaxnav.experiments`` train
through ``train_seeds``.

The compiled program is ``Trainer.sharded`` (``jaxnav.programs`` keeps it traced on disk);
everything here runs on the host between two of its calls. Over several hosts every process
runs this loop, and process 0 alone (``is_primary``) writes the run directory and prints.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils

from jaxnav import loggers, programs, run_dir, sharding
from jaxnav.checkpoints import Checkpoints
from jaxnav.config import TrainConfig
from jaxnav.evaluate import evaluate_seeds, mean_of, print_eval_table
from jaxnav.train import DIVERGENCE_QUANTITIES, METRIC_NAMES, Trainer


def start_hosts(coordinator: str, num_processes: int, process_id: int) -> None:
    """``jax.distributed.initialize`` for a run over several processes, before anything else
    touches the JAX backend; ``ValueError`` (one line) when the coordinator cannot be reached."""
    try:
        jax.distributed.initialize(coordinator, num_processes, process_id)
    except Exception as e:  # noqa: BLE001 (XLA raises several kinds for an unreachable peer)
        raise ValueError(f"--coordinator {coordinator}: {str(e).splitlines()[0]}") from None


def is_primary() -> bool:
    """Process 0 of a run over several hosts (and the only process otherwise) writes the
    run directory and prints progress."""
    return jax.process_index() == 0


def print_primary(*args: Any, **kwargs: Any) -> None:
    """``print`` on process 0 only."""
    if is_primary():
        print(*args, **kwargs)


def open_run(trainer: Trainer, partial: Path, checkpointing: dict[str, int] | None) -> None:
    """Create the run directory ``partial`` with its config.json, ``checkpointing`` (the
    checkpoint flags, kept for ``--resume``) in it; None: continue the run already there.
    Process 0 writes; with several processes all of them wait until it has."""
    if checkpointing is not None and is_primary():
        run_dir.create(partial, trainer, checkpointing=checkpointing)
    if jax.process_count() > 1:
        multihost_utils.sync_global_devices("jaxnav: run directory created")


class Progress:
    """Progress lines, one per logging interval, printed between the compiled intervals."""

    def __init__(
        self, config: TrainConfig, quiet: bool, sinks: Sequence[loggers.MetricsLogger] = ()
    ):
        self.config, self.quiet = config, quiet
        self.sinks = sinks  # TensorBoard, W&B: each interval's metrics, quiet or not
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
        for sink in self.sinks:
            sink.log(metrics, steps)
        if self.quiet:
            return
        elapsed = now - self.start
        total = self.config.num_logs * self.config.steps_per_log
        sps = (steps - self.start_steps) * self.config.num_seeds / max(elapsed, 1e-9)
        eta = (total - steps) * self.config.num_seeds / max(sps, 1e-9)
        mean = lambda k: float(np.mean(metrics[k]))  # noqa: E731
        print(
            f"[{elapsed:6.1f}s] steps {steps:>9,}/{total:,} ({100 * steps / total:3.0f}%) | "
            f"{sps:>8,.0f} steps/s | train success ({self.config.algorithm.acting}) "
            f"{mean('success_rate'):.3f} | "
            f"return {mean('mean_return'):6.2f} | length {mean('mean_length'):5.1f} steps | "
            f"loss {mean('loss'):.4f} | eps {mean('epsilon'):.2f} | ETA {eta:4.0f}s",
            flush=True,
        )

    def steps_per_second(self, env_steps: np.ndarray) -> np.ndarray:
        """Env steps/s (all seeds) of each logging interval (NaN where not timed)."""
        dt = np.array([self.seconds.get(int(s), np.nan) for s in env_steps])
        interval = self.config.steps_per_log * self.config.num_seeds
        return interval / dt


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
        else Checkpoints(
            saving.directory / "checkpoints",
            saving.keep,
            writer=is_primary(),
            inputs=run_dir.input_checksums(saving.directory, c),
        )
    )
    done = 0 if checkpoints is None else checkpoints.newest_intact(_warn) or 0
    if done:
        try:
            legacy = trainer.legacy_checkpoint_layouts(state_like)
            done, state, metrics, meta = checkpoints.restore(state_like, metrics, done, legacy)
            state = sharding.place(state, trainer.mesh, trainer.state_specs(state_like))
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


def _stop_if_signalled(signals: Sequence[int], steps: int) -> None:
    # this process's own signals: finishing runs on the primary alone, so no collective here
    if signals:
        raise Interrupted(steps, signals[0])


def _warn(message: str) -> None:
    print_primary(f"warning: {message}", file=sys.stderr, flush=True)


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


def finish_run(
    trainer: Trainer,
    params: Any,
    metrics: dict[str, np.ndarray],
    progress: Progress,
    partial: Path,
    out: Path,
    times: tuple[float, float, float],
    signals: Sequence[int] = (),
) -> None:
    """Evaluate the trained seeds, complete the run in ``partial`` and rename it to ``out``;
    ``times`` are the compile and train seconds and the run's start (``perf_counter``).
    ``Interrupted`` when ``signals`` (``Saving.signals``) has one before or after the
    evaluation, which can take minutes (nothing is written, and ``--resume`` evaluates again
    from the final checkpoint), or after a step of the final save (``--resume`` saves again,
    or only renames the finished run)."""
    config = trainer.config
    steps = config.num_logs * config.steps_per_log
    _stop_if_signalled(signals, steps)
    compile_s, train_s, t_start = times
    # wall-clock timing apart from metrics.csv, which is bitwise reproducible
    sps = progress.steps_per_second(metrics["env_steps"][0])
    shape = metrics["env_steps"].shape
    timing = {"env_steps": metrics["env_steps"], "sps": np.broadcast_to(sps, shape)}
    t0 = time.perf_counter()
    trained = rand = None  # eval_episodes 0: not measured, so null in summary.json, not zeros
    if config.eval_episodes:
        trained = evaluate_seeds(trainer, params, config.eval_episodes, seed=10_000)
        rand = evaluate_seeds(trainer, params, config.eval_episodes, 10_000, "random")
    eval_s = time.perf_counter() - t0
    _stop_if_signalled(signals, steps)

    # complete the hidden sibling, then rename: a crash never leaves half a run at ``out``
    seeds = run_dir.seeds_of(config)
    run_dir.write_trained(partial, config, metrics, params)
    _stop_if_signalled(signals, steps)  # a signal while saving: --resume saves again
    run_dir.write_metrics_csv(partial / "timing.csv", timing, seeds)
    summary = {
        "env": config.env,
        "seeds": seeds,
        "eval_episodes": config.eval_episodes,
        "trained": None if trained is None else mean_of(trained),
        "trained_per_seed": trained,
        "random_policy": None if rand is None else mean_of(rand),
        "compile_s": compile_s,
        "train_s": train_s,
        "eval_s": eval_s,
        "wall_s": time.perf_counter() - t_start,
    }
    run_dir.write_json(partial / "summary.json", summary)  # last: marks the run finished
    _stop_if_signalled(signals, steps)  # finished: --resume only renames it
    run_dir.complete(partial, out)  # repeatable through --resume if stopped or refused
    if trained is None:
        print("no final evaluation (eval_episodes 0)")
    else:
        policies = {"trained (greedy)": summary["trained"], "random": summary["random_policy"]}
        print_eval_table(config.env, policies)
    print(
        f"compile {compile_s:.1f}s, train {train_s:.1f}s, eval {eval_s:.1f}s, "
        f"total {summary['wall_s']:.1f}s; run saved to {out}"
    )


EXIT_DISK_FULL = 4


def disk_full(prog: str, error: Exception, resume: str) -> int:
    """Report an ``OSError`` during training or finishing: no space left on the device
    is one line with the resume command, exit code 4 (the last good checkpoint stays, since
    orbax renames a checkpoint only once it is complete); any other is raised again."""
    if not is_disk_full(error):
        raise error
    where = getattr(error, "filename", None) or "the run directory"
    print(
        f"{prog}: no space left on device while writing {where}; the last good checkpoint "
        f"is kept; free space, then continue with: {resume}",
        file=sys.stderr,
    )
    return EXIT_DISK_FULL


def is_disk_full(error: BaseException | None) -> bool:
    """ENOSPC or EDQUOT here or in the exceptions it wraps (orbax and tensorstore re-raise
    their writers' errors, some only as text)."""
    seen = 0
    while error is not None and seen < 20:
        if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        if "No space left on device" in str(error) or "Disk quota exceeded" in str(error):
            return True
        error, seen = error.__cause__ or error.__context__, seen + 1
    return False


@contextlib.contextmanager
def stop_on_signals(received: list[int]) -> Iterator[None]:
    """Within the block, SIGINT/SIGTERM append to ``received`` (the training loop saves and
    stops); a second one ends the process at once, as the default would. The previous
    handlers are restored after it. No-op outside the main thread (Python only signals that
    one)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        if received:  # asked twice: stop now, the last checkpoint stays
            print(
                f"\n{signal.Signals(signum).name} again: stopping now without saving; "
                "--resume continues from the last checkpoint",
                file=sys.stderr,
                flush=True,
            )
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
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
