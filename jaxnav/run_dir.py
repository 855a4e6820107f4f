"""A training run on disk: config.json, metrics.csv, params/ (orbax), summary.json, eval.json.

The one writer and reader of run directories: ``python -m jaxnav.train`` (through
``jaxnav.runner``) and ``jaxnav.experiments`` write them, ``jaxnav.evaluate``,
``jaxnav.render`` and the generalization experiment read them (``load_run_on``).
"""

from __future__ import annotations

import csv
import dataclasses
import errno
import fcntl
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from jaxnav.agents import dqn
from jaxnav.checkpoints import manifest_damage, sha256_of, this_process_only, write_manifest
from jaxnav.config import TrainConfig, upgrade_saved
from jaxnav.host import host_info, package_version
from jaxnav.registration import config_fields, env_config
from jaxnav.safe_io import WRITE_FAULTS, WriteFault, atomic_output, write_text
from jaxnav.train import Trainer

PACKAGES = ("jaxnav", "jax", "jaxlib", "flax", "optax", "chex", "orbax-checkpoint", "mujoco-mjx")


def environment_info() -> dict[str, Any]:
    """What a run's config.json records of where it ran: ``host_info`` and the packages."""
    return {
        **host_info(),
        "jax_backend": jax.default_backend(),
        "packages": {name: package_version(name) for name in PACKAGES},
    }


def partial_dir(out: Path) -> Path:
    """Where the run for ``out`` lives until it is complete (then renamed to ``out``);
    ``ValueError`` for a path without a name ('' or '.')."""
    if out.name in ("", "."):
        raise ValueError(f"{str(out)!r}: not a run directory name (give one, not '' or '.')")
    return out.with_name(f".{out.name}.partial")


def find_unfinished(run: Path) -> tuple[Path, Path]:
    """``(out, partial)`` of the unfinished run named by its ``out`` or its partial directory;
    ``ValueError`` if there is none."""
    if run.name.startswith(".") and run.name.endswith(".partial"):
        run = run.with_name(run.name[1 : -len(".partial")])
    partial = partial_dir(run)
    if not (partial / "config.json").is_file():
        if (run / "summary.json").is_file():
            raise ValueError(f"--resume {run}: the run is complete; nothing to resume")
        raise ValueError(f"--resume {run}: no unfinished run there (no {partial / 'config.json'})")
    return run, partial


def check_out_path(out: Path, flag: str = "--out") -> None:
    """``ValueError`` for an ``out`` a run can never be renamed to: an empty name or a
    symbolic link (dangling, a loop, or to a directory the rename would not follow)."""
    if out.name in ("", ".", ".."):
        raise ValueError(f"{flag} {str(out)!r}: not a run directory name (give one)")
    if out.is_symlink():
        raise ValueError(
            f"{flag} {out}: is a symbolic link (to {os.readlink(out)}); give the directory itself"
        )


def check_completable(out: Path, flag: str = "--out") -> None:
    """``ValueError`` if the finished run cannot be renamed to ``out``: it must be absent or
    an empty directory."""
    check_out_path(out, flag)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"{flag} {out}: already exists and is not an empty directory")


def check_writable(out: Path) -> None:
    """Raise ``ValueError`` if a run cannot be written to ``out`` (checked before any work),
    ``WriteFault`` where the machine refuses to write there (a read-only or full disk)."""
    check_completable(out)
    if os.path.lexists(partial_dir(out)):
        raise ValueError(
            f"--out {out}: an unfinished run is in {partial_dir(out)}; continue it with "
            f"--resume {out} or delete it"
        )
    parent = out.parent if not out.exists() else out
    while not parent.exists():
        parent = parent.parent
    try:  # really create a file: permission bits lie on read-only or special filesystems
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as e:
        if e.errno in WRITE_FAULTS:  # a read-only or full disk: the machine's, exit 4
            raise WriteFault(parent, e.errno) from None
        raise ValueError(f"--out {out}: {parent} is not a writable directory") from None


LOCK = "lock"  # in the partial directory, removed before the rename to ``out``


class RunLock:
    """An exclusive ``fcntl.flock`` on ``partial/lock`` while this process writes the run:
    the OS releases it when the process ends, however it ends, so a lock never goes stale."""

    def __init__(self, partial: Path, fd: int):
        self.partial, self.fd = partial, fd

    def release(self) -> None:
        """Drop the lock (it also goes when the process ends)."""
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def lock_run(partial: Path, new: bool) -> RunLock:
    """Lock the run directory ``partial`` for writing (``new``: create it first);
    ``ValueError`` (one line) when another process writes it or is creating it, ``OSError``
    (its filename ``partial``) when it cannot be written."""
    if new:
        try:
            partial.mkdir(parents=True)
        except FileExistsError:
            raise ValueError(f"{partial}: another process started a run there just now") from None
    try:  # really create a file: permission bits lie on read-only or special filesystems
        with tempfile.TemporaryFile(dir=partial):
            pass
    except OSError as e:  # the directory, not a random temporary name, is what the user fixes
        raise OSError(e.errno, e.strerror, str(partial)) from None
    path = partial / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        os.close(fd)
        raise ValueError(
            f"{partial}: another process (pid {holder}) is writing this run; wait for it or stop it"
        ) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return RunLock(partial, fd)


def is_finished(partial: Path) -> bool:
    """Whether the unfinished run in ``partial`` was completed but not yet renamed (its
    summary.json, written last, is there): ``--resume`` only renames it."""
    return (partial / "summary.json").is_file()


def complete(partial: Path, out: Path) -> None:
    """Rename the finished directory ``partial`` to ``out`` (an empty directory at ``out``,
    checked before any work, is replaced): a crash never leaves half a run at ``out``.
    Repeatable: an interrupted or refused completion is finished by calling it again (through
    ``--resume``); ``ValueError`` when ``out`` became something the run cannot replace."""
    try:
        check_completable(out)
    except ValueError as e:
        raise ValueError(
            f"{e}; cannot rename the finished run to it: it is complete in {partial}; clear "
            f"{out}, then --resume {out}"
        ) from None
    # the final state is params/; dropped before the rename so a finished run never has them
    shutil.rmtree(partial / "checkpoints", ignore_errors=True)
    (partial / LOCK).unlink(missing_ok=True)
    try:
        if out.exists():
            out.rmdir()
        partial.rename(out)
    except OSError as e:  # something appeared at ``out`` since the check just now
        if e.errno in (errno.ENOSPC, errno.EDQUOT):
            raise
        raise ValueError(
            f"--out {out}: cannot rename the finished run to it ({e.strerror}); it is complete "
            f"in {partial}: clear {out}, then --resume {out}"
        ) from None


def config_to_json(config: TrainConfig) -> dict[str, Any]:
    d = dataclasses.asdict(config)
    d["hidden_sizes"] = list(config.hidden_sizes)
    return d


def config_from_json(d: dict[str, Any]) -> TrainConfig:
    """The ``TrainConfig`` saved by ``config_to_json``, also by an older jaxnav (its
    ``updates_per_iteration`` becomes the same training's ``replay_ratio``)."""
    d = upgrade_saved(d)
    d["hidden_sizes"] = tuple(d["hidden_sizes"])
    return TrainConfig(**d)


def write_json(path: Path, obj: Any) -> None:
    """Write atomically: a crash leaves the old file or the new one, never half of one
    (``WriteFault`` for a full disk and the like)."""
    write_text(path, json.dumps(obj, indent=2) + "\n")


def write_metrics_csv(path: Path, metrics: dict[str, np.ndarray], seeds: list[int]) -> None:
    """One row per (seed, logging interval); ``metrics`` arrays are [num_seeds, num_logs]."""
    names = list(metrics)
    with atomic_output(path) as tmp, tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["seed", *names])
        for i, seed in enumerate(seeds):
            for t in range(np.asarray(metrics[names[0]]).shape[1]):
                w.writerow([seed, *(_fmt(metrics[n][i, t]) for n in names)])


def _fmt(v: Any) -> str:
    v = np.asarray(v).item()
    return str(v) if isinstance(v, int) else repr(float(v))


def save_params(run: Path, params: Any) -> None:
    """Final network parameters (all seeds stacked on axis 0) as an orbax checkpoint, with
    the checksum of each of its files (``checkpoints.MANIFEST``), verified on loading."""
    with ocp.StandardCheckpointer(multiprocessing_options=this_process_only()) as ckpt:
        ckpt.save((run / "params").absolute(), jax.device_get(params))
    write_manifest(run / "params")


def load_params(run: Path, like: Any) -> Any:
    """Parameters saved by ``save_params``; ``like`` gives their structure (abstract is fine).
    ``ValueError`` when the saved arrays are not those ``like`` describes: orbax restores a
    (16,) bias into a (32,) one without a word, so the names, shapes and dtypes are compared
    first (a config.json edited after training, e.g. its hidden_sizes)."""
    abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), like)
    path = (run / "params").absolute()
    damage = manifest_damage(path)  # None also for runs saved before params/ had checksums
    if damage is not None:
        raise ValueError(
            f"{run / 'params'}: damaged, {damage}; restore the run from a backup or train "
            "it again"
        )
    with ocp.StandardCheckpointer(multiprocessing_options=this_process_only()) as ckpt:
        try:
            saved = ckpt.metadata(path).item_metadata
        except (KeyError, ValueError, TypeError, OSError) as e:  # orbax's, for a bad _METADATA
            raise unreadable_params(run, e) from None
        if not jax.tree.leaves(saved):  # orbax logs a bad _METADATA and returns nothing
            raise unreadable_params(run, ValueError("_METADATA lists no arrays"))
        _check_saved_params(run, saved, abstract)
        try:
            return ckpt.restore(path, abstract)
        except (KeyError, ValueError, TypeError, OSError) as e:  # damage in a run saved before
            raise unreadable_params(run, e) from None


def unreadable_params(run: Path, error: Exception) -> ValueError:
    """The one-line error for a run's params/ that orbax cannot read."""
    what = " ".join(str(error).split())[:200]  # orbax's messages span lines
    return ValueError(
        f"{run / 'params'}: unreadable ({type(error).__name__}: {what}); restore the run from "
        "a backup or train it again"
    )


def _check_saved_params(run: Path, saved: Any, abstract: Any) -> None:
    def arrays(tree: Any) -> dict[str, tuple[tuple[int, ...], str]]:
        flat = jax.tree_util.tree_flatten_with_path(tree)[0]
        return {jax.tree_util.keystr(k): (tuple(v.shape), str(v.dtype)) for k, v in flat}

    have, want = arrays(saved), arrays(abstract)
    for name in sorted(have.keys() | want.keys()):
        if have.get(name) != want.get(name):
            shown = {n: "absent" if a is None else f"{a[1]}{list(a[0])}" for n, a in (
                ("saved", have.get(name)), ("config", want.get(name))
            )}  # fmt: skip
            raise ValueError(
                f"{run}: the run's parameters do not match its config.json ({name}: saved "
                f"{shown['saved']}, the config gives {shown['config']}); was config.json edited?"
            )


def seeds_of(config: TrainConfig) -> list[int]:
    return [config.seed + i for i in range(config.num_seeds)]


def seed_keys(config: TrainConfig) -> jax.Array:
    """One independent key per seed: seed ``s`` trains the same whether run alone or vmapped."""
    return jnp.stack([jax.random.key(s) for s in seeds_of(config)])


def load_config(run: Path) -> TrainConfig:
    """A run's config; ``ValueError`` for a directory that is no run, naming the command that
    continues an unfinished run when there is one at ``run``."""
    path = run / "config.json"
    if not path.is_file() and (partial_dir(run) / "config.json").is_file():
        raise unfinished_error(run)
    if not path.is_file():
        raise ValueError(f"{run}: not a run directory (no config.json)")
    try:
        return config_from_json(json.loads(path.read_text())["config"])
    except (KeyError, TypeError, ValueError) as e:  # ValueError: JSON, UTF-8, a value
        raise ValueError(f"{path}: unreadable run config ({e})") from None


def load_network(run: Path) -> dict[str, Any]:
    """The network description saved with the run (sizes, flags, ``obs_size``,
    ``onehot_sizes``)."""
    try:
        return json.loads((run / "config.json").read_text())["network"]
    except (OSError, KeyError, TypeError, json.JSONDecodeError) as e:
        raise ValueError(f"{run / 'config.json'}: unreadable network description ({e})") from None


def load_checkpointing(run: Path) -> dict[str, int]:
    """The checkpoint flags saved with a run by ``python -m jaxnav.train`` (none in runs
    written before they were saved)."""
    return json.loads((run / "config.json").read_text()).get("checkpointing", {})


def input_checksums(run: Path, config: TrainConfig) -> dict[str, str]:
    """SHA-256 of the files a run's training state depends on: its config.json and the
    files its mazes are read from (the env config's ``input_files``: maze files, a map's
    image); saved with every checkpoint and compared on ``--resume``."""
    sums = {"config.json": sha256_of(run / "config.json")}
    env = env_config(config.env, **config.env_kwargs)
    for f in getattr(env, "input_files", list)():
        sums[f"maze file {f}"] = sha256_of(Path(f))
    return sums


def config_document(config: TrainConfig, trainer: Trainer) -> dict[str, Any]:
    """The contents of a run's config.json: effective config, network, software and machine."""
    return {
        "config": config_to_json(config),
        "network": {
            "num_actions": trainer.env.num_actions,
            "hidden_sizes": list(config.hidden_sizes),
            "dueling": config.dueling,
            "obs_size": trainer.obs_size,
            "onehot_sizes": trainer.network.onehot_sizes,
        },
        "environment": environment_info(),
    }


def create(run: Path, trainer: Trainer, **sections: Any) -> None:
    """Make the run directory ``run`` with its config.json: ``config_document`` of the
    trainer's config, then ``sections`` (e.g. ``checkpointing``)."""
    run.mkdir(parents=True, exist_ok=True)  # ``lock_run`` may have made it
    write_json(run / "config.json", {**config_document(trainer.config, trainer), **sections})


def write_trained(
    run: Path, config: TrainConfig, metrics: dict[str, np.ndarray], params: Any
) -> None:
    """A trained run's metrics.csv (one row per seed and logging interval) and params/
    (replacing those of an earlier, interrupted write: finishing is repeatable)."""
    write_metrics_csv(run / "metrics.csv", metrics, seeds_of(config))
    shutil.rmtree(run / "params", ignore_errors=True)  # orbax refuses to overwrite
    save_params(run, params)


def unfinished_error(run: Path) -> ValueError:
    """The error for using the unfinished run ``run`` (its ``--out`` or its partial directory)
    as a trained one: it has no parameters yet; ``--resume`` finishes it."""
    if run.name.startswith(".") and run.name.endswith(".partial"):
        run = run.with_name(run.name[1 : -len(".partial")])
    return ValueError(
        f"{run}: an unfinished run (training stopped before its end; no trained parameters "
        f"yet); finish it with: python -m jaxnav.train --resume {run}"
    )


def load_trained_params(run: Path, trainer: Trainer) -> Any:
    """The run's parameters (seeds stacked), shaped by ``trainer``'s network."""
    if not (run / "params").exists() and (run / "checkpoints").is_dir():
        raise unfinished_error(run)
    init = lambda k: trainer.network.init(k, jnp.zeros((1, trainer.obs_size)))  # noqa: E731
    like = jax.eval_shape(jax.vmap(init), seed_keys(trainer.config))
    return load_params(run, like)


# What a policy needs of an env other than its own (another id, e.g. a maze file): the fields
# that shape its observation and its actions' effect (and the robot's fast CPU backend)
CARRIED_FIELDS = (
    "num_lasers", "laser_fov", "laser_range", "obs_absolute", "obs_proximity", "obs_heading",
    "obs_goal_bearing", "waypoint_distance", "waypoint_moves", "frames", "goal_range",
    "obs_last_action", "obs_radius", "trail_cell", "lidar_map", "speed", "turn_speed", "dt",
    "radius",
    "backend",  # robot
    "size", "obs_mode", "sensor_radius", "waypoint_cells",  # grid envs
)  # fmt: skip
# those of them that set what the network reads: a policy only runs with the trained values
OBSERVATION_FIELDS = frozenset(
    {"num_lasers", "laser_fov", "laser_range", "obs_absolute", "obs_proximity", "obs_heading"}
    | {"obs_goal_bearing", "waypoint_distance", "waypoint_moves", "frames", "goal_range"}
    | {"obs_last_action", "obs_radius", "trail_cell"}
    | {"obs_mode", "sensor_radius", "waypoint_cells"}
)
# carried only where set: the env kwargs of policies without them stay as they were
CARRIED_IF_SET = frozenset({"trail_cell", "lidar_map"})


def policy_env(
    own_env: str,
    own_kwargs: dict[str, Any],
    trained: dict[str, Any],
    env: str | None,
    overrides: dict[str, Any],
) -> tuple[str, dict[str, Any]]:
    """``(env id, env kwargs)`` to run a policy trained on ``own_env`` with ``own_kwargs``
    (whose env config's fields are ``trained``) on: its own env with ``overrides`` on its
    kwargs, or ``env`` with the policy's ``CARRIED_FIELDS`` and ``overrides``. ``ValueError``
    (one line) for an override of an ``OBSERVATION_FIELDS`` field away from its trained value."""
    for name, value in overrides.items():
        if name in OBSERVATION_FIELDS and name in trained and value != trained[name]:
            raise ValueError(
                f"--env-arg {name}={value!r}: the policy was trained on observations with "
                f"{name}={trained[name]!r}; leave it out (it goes with the policy)"
            )
    if env is None or env == own_env:
        return own_env, {**own_kwargs, **overrides}
    fields = config_fields(env)  # a grid's size is no robot's
    carried = {
        k: trained[k]
        for k in CARRIED_FIELDS
        if k in trained and k in fields and (trained[k] or k not in CARRIED_IF_SET)
    }
    kwargs = {**carried, **overrides}
    env_config(env, **kwargs)  # ValueError for bad overrides
    return env, kwargs


def run_env(
    config: TrainConfig, env: str | None, overrides: dict[str, Any]
) -> tuple[str, dict[str, Any]]:
    """``policy_env`` for the run trained with ``config``: the env a run directory's policy is
    evaluated or drawn on, its observation settings carried to another env id."""
    trained = dataclasses.asdict(env_config(config.env, **config.env_kwargs))
    return policy_env(config.env, config.env_kwargs, trained, env, overrides)


def load_run_on(
    run: Path, env: str, env_kwargs: dict[str, Any]
) -> tuple[TrainConfig, Trainer, Any]:
    """``(config, trainer, params)`` of the trained run directory ``run`` set up on ``env``
    with exactly ``env_kwargs``; ``ValueError`` (or ``FileNotFoundError``) where the run or the
    env is bad or the env's observations do not fit the run's network."""
    config = load_config(run)
    config = dataclasses.replace(config, env=env, env_kwargs=dict(env_kwargs))
    config.validate()
    trainer = Trainer(config)
    network = load_network(run)
    onehot = network.get("onehot_sizes")  # runs before it was saved had none
    want = (network["obs_size"], None if onehot is None else tuple(onehot))
    dqn.check_input_fits(config.env, trainer.network_input, want)
    return config, trainer, load_trained_params(run, trainer)
