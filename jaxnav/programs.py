"""The compiled programs of a training run, with their traced form kept on disk.

XLA's persistent cache (``enable_compilation_cache``) skips compiling a program seen
before, but JAX must still trace the Python code to know which program it is: for the MJX
robot that trace is most of a second run's start-up. So the traced programs (``jax.export``,
StableHLO) are stored next to the XLA cache, under a key made of everything that decides
them: the effective config, a hash of this package's source, the versions of the packages
that trace (jax, flax, optax, mujoco-mjx), a maze file's content and the devices. A second
run with the same key deserializes them and goes straight to XLA (a cache hit there too); a
run over several processes traces every time. Compiling through the exported program is
what the first run does as well, so both runs execute the same program.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import pickle
import stat
import sys
import tempfile
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxnav.host import package_version
from jaxnav.safe_io import remove_quietly
from jaxnav.train import Trainer, jit_training

FORMAT = 1  # bump when what is stored changes
PACKAGES = ("jax", "jaxlib", "flax", "optax", "mujoco", "mujoco-mjx")
# the Triton calls of the Pallas kernels (agents.layer_norm) have no guarantee across jax
# versions; stored programs are only read back by the versions of the key, so they may be kept
UNVERSIONED_CALLS = [
    jax.export.DisabledSafetyCheck.custom_call(target)
    for target in ("__gpu$xla.gpu.triton", "triton_kernel_call_ffi")
]


@dataclasses.dataclass
class TrainingPrograms:
    """``init(keys) -> state``; ``interval(state, log) -> (state, metrics)`` (state donated);
    ``state_like`` the state's abstract values (shapes, dtypes); ``metrics_like`` one
    interval's abstract metrics; ``from_cache`` whether tracing was skipped."""

    init: Callable[..., Any]
    interval: Callable[..., Any]
    state_like: Any
    metrics_like: dict[str, jax.ShapeDtypeStruct]
    from_cache: bool


def enable_compilation_cache() -> None:
    """Persist compiled programs across runs (``JAXNAV_CACHE_DIR``, default
    ``~/.cache/jaxnav/xla``; set it to an empty string to disable): a second run of the same
    config skips XLA compilation. Every command line turns it on.

    Only the user running jaxnav (and root) may write there: what the cache holds is run (XLA
    executables, and programs unpickled by ``_load``). A directory that others can write is
    refused with a one-line warning, and the run goes on without the cache."""
    path = os.environ.get("JAXNAV_CACHE_DIR", str(Path.home() / ".cache" / "jaxnav" / "xla"))
    unsafe = path and writable_by_others(Path(path))
    if unsafe:
        print(
            f"warning: JAXNAV_CACHE_DIR {path}: {unsafe}; the compilation cache is not used",
            file=sys.stderr,
            flush=True,
        )
        jax.config.update("jax_compilation_cache_dir", None)  # off, also if on before
    elif path:
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def writable_by_others(path: Path) -> str:
    """Why someone other than this user (or root) could change what ``path`` holds: it, or a
    directory above it, is owned by another user or writable by the group or others (without
    the sticky bit, which keeps others from renaming our entries, as in /tmp); ``""`` if no
    one can. A missing ``path`` is judged by the directories that exist above it.

    Why a mode check rather than a format that cannot run code: the cache's main content is
    XLA's persistent cache of compiled executables, which run as they are loaded whatever
    format our own entries used; so the directory itself must be writable by this user
    alone."""
    me = os.geteuid()
    for p in [path.absolute(), *path.absolute().parents]:
        try:
            st = p.stat()
        except FileNotFoundError:
            continue
        if st.st_uid not in (me, 0):
            return f"{p} is owned by another user (uid {st.st_uid})"
        if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH) and not st.st_mode & stat.S_ISVTX:
            return f"{p} is writable by other users (mode {stat.S_IMODE(st.st_mode):o})"
    return ""


def cache_directory() -> Path | None:
    """Where traced programs are kept: ``programs/`` in XLA's persistent cache directory when
    that cache is on (``enable_compilation_cache``), else nowhere. Not used in a run over
    several processes."""
    xla = jax.config.jax_compilation_cache_dir
    return Path(xla) / "programs" if xla else None


def compile_training(trainer: Trainer, keys: jax.Array, cache: Path | None) -> TrainingPrograms:
    """The compiled training programs for the seeds of ``keys``; traced programs are read from
    and written to ``cache`` (a directory; ``None`` to trace every time)."""
    # several processes trace for themselves: each must compile the very program the others
    # do, which one process's cache entry would not guarantee
    off = cache is None or jax.process_count() > 1
    directory = None if off else cache / _key(trainer, keys)
    stored = _load(directory)
    from_cache = stored is not None
    if stored is None:
        blob = _trace(trainer, keys)
        _save(directory, blob)
        # both runs compile the deserialized programs, so both run the same one (and the
        # second finds it in XLA's cache)
        stored = _from_blob(blob)
    state_like, treedef = stored["state_like"], stored["treedef"]
    leaves_like = tuple(jax.tree.leaves(state_like))
    init, interval = stored["init"], stored["interval"]
    log_like = jax.ShapeDtypeStruct((), np.int32)

    def compile_init() -> Any:
        with jax.set_mesh(trainer.mesh):  # the device count the programs were exported for
            return _jit_exported(init, trainer.mesh).lower(keys).compile()

    # XLA compiles outside the GIL: init compiles beside the interval, on a second core
    with ThreadPoolExecutor(1) as pool, jax.set_mesh(trainer.mesh):
        pending_init = pool.submit(compile_init)
        flat_interval = _jit_exported(interval, trainer.mesh, donate_argnums=0)
        flat_interval = flat_interval.lower(leaves_like, log_like).compile()
        flat_init = pending_init.result()

    def run_init(keys: jax.Array) -> Any:
        return jax.tree.unflatten(treedef, flat_init(keys))

    def run_interval(state: Any, log: Any) -> tuple[Any, dict]:
        leaves, metrics = flat_interval(tuple(jax.tree.leaves(state)), log)
        return jax.tree.unflatten(treedef, leaves), metrics

    return TrainingPrograms(
        init=run_init,
        interval=run_interval,
        state_like=state_like,
        metrics_like=flat_interval.out_info[1],
        from_cache=from_cache,
    )


def _jit_exported(exported: jax.export.Exported, mesh: Any, **kwargs: Any) -> Any:
    """``jit`` of an exported program on ``mesh``'s devices, laid out as it was exported."""
    args, _ = jax.tree.unflatten(exported.in_tree, exported.in_shardings_jax(mesh))
    out = jax.tree.unflatten(exported.out_tree, exported.out_shardings_jax(mesh))
    return jit_training(exported.call, in_shardings=args, out_shardings=out, **kwargs)


def _key(trainer: Trainer, keys: jax.Array) -> str:
    config = dataclasses.asdict(trainer.config)
    parts = {
        "format": FORMAT,
        "config": config,
        "keys": [list(keys.shape), str(keys.dtype)],
        "source": _source_hash(),
        "packages": {p: package_version(p) for p in PACKAGES},
        "devices": [d.device_kind for d in jax.devices()],
    }
    files = getattr(trainer.env.config, "input_files", list)()
    if files:
        parts["maze_files"] = [hashlib.sha256(Path(f).read_bytes()).hexdigest() for f in files]
    if trainer.init_params is not None:  # init_from's weights are constants of the program
        digest = hashlib.sha256()
        for leaf in jax.tree.leaves(trainer.init_params):
            digest.update(np.asarray(leaf).tobytes())
        parts["init_params"] = digest.hexdigest()
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _source_hash() -> str:
    digest = hashlib.sha256()
    root = Path(__file__).parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _trace(trainer: Trainer, keys: jax.Array) -> dict[str, Any]:
    """Export the programs over flat lists of arrays (the state's pytree classes, e.g. optax's,
    cannot be serialized; its structure is pickled beside them)."""
    init, interval, state_like = trainer.sharded(keys)
    leaves, treedef = jax.tree.flatten(state_like)

    def flat_init(keys: jax.Array) -> tuple[jax.Array, ...]:
        return tuple(jax.tree.leaves(init(keys)))

    def flat_interval(leaves: tuple[jax.Array, ...], log: jax.Array) -> tuple[tuple, dict]:
        state, metrics = interval(jax.tree.unflatten(treedef, leaves), log)
        return tuple(jax.tree.leaves(state)), metrics

    log_like = jax.ShapeDtypeStruct((), np.int32)

    def export(fn: Callable, *args: Any) -> bytes:
        return jax.export.export(jax.jit(fn), disabled_checks=UNVERSIONED_CALLS)(*args).serialize()

    return {
        "init": export(flat_init, keys),
        "interval": export(flat_interval, tuple(leaves), log_like),
        "treedef": treedef,
        "leaves": [(x.shape, x.dtype) for x in leaves],
    }


def _from_blob(blob: dict[str, Any]) -> dict[str, Any]:
    leaves = [jax.ShapeDtypeStruct(shape, dtype) for shape, dtype in blob["leaves"]]
    return {
        "init": jax.export.deserialize(blob["init"]),
        "interval": jax.export.deserialize(blob["interval"]),
        "state_like": jax.tree.unflatten(blob["treedef"], leaves),
        "treedef": blob["treedef"],
    }


def _load(directory: Path | None) -> dict[str, Any] | None:
    """The stored programs (``_from_blob``), or ``None`` if there are none or they do not
    read back (a damaged or foreign entry is traced again and replaced)."""
    path = None if directory is None else directory / "programs.pkl"
    if path is None or not path.exists() or writable_by_others(path):
        return None  # a file others could have written is never unpickled: traced again
    try:
        with open(path, "rb") as f:
            return _from_blob(pickle.load(f))
    except Exception:  # noqa: BLE001
        return None


def _save(directory: Path | None, blob: dict[str, Any]) -> None:
    """Written to a temporary file and renamed, so a reader never sees half of one; a cache
    that cannot be written (read-only, full) is left alone: it only costs start-up time."""
    if directory is None:
        return
    tmp = None
    try:
        directory.mkdir(parents=True, exist_ok=True)
        # a name of its own: processes sharing the cache may write it at once
        with tempfile.NamedTemporaryFile(dir=directory, delete=False, suffix=".tmp") as f:
            tmp = Path(f.name)
            pickle.dump(blob, f)
        os.replace(tmp, directory / "programs.pkl")
    except OSError:
        if tmp is not None:  # a full disk: no half-written entry left behind
            remove_quietly(tmp)
