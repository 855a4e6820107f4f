"""Checkpoints of an unfinished training run: every seed's full ``TrainState`` (params, target,
optimizer state, replay buffer, env states, RNG keys, hyperparameters, divergence flags) and
the metrics of the logging intervals done so far, so a resumed run continues bitwise where the
saved one stopped.

One orbax ``CheckpointManager`` directory; the step number is the count of logging intervals
done. Orbax writes each checkpoint to a temporary directory and renames it when complete, so a
crash mid-save leaves the previous checkpoints intact (and the half-written one is ignored and
cleaned up on the next open).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from jaxnav.sharding import is_key


def this_process_only() -> ocp.options.MultiprocessingOptions:
    """Orbax options for files that one process reads or writes on its own: in a run over
    several hosts, process 0 writes the run directory and the others only read it."""
    me = jax.process_index()
    return ocp.options.MultiprocessingOptions(primary_host=me, active_processes={me})


def _to_disk(tree: Any) -> Any:
    """Typed PRNG keys as their raw words (host arrays): orbax stores plain arrays only."""
    return jax.tree.map(lambda x: np.asarray(jax.random.key_data(x)) if is_key(x) else x, tree)


def _disk_like(tree: Any) -> Any:
    """Shapes and dtypes of ``_to_disk(tree)``."""
    return jax.tree.map(lambda x: jax.eval_shape(jax.random.key_data, x) if is_key(x) else x, tree)


def _from_disk(tree: Any, like: Any) -> Any:
    def back(x, like_leaf):
        if not is_key(like_leaf):
            return x
        key = jax.random.wrap_key_data(x)  # the default impl, which made the saved keys
        if key.dtype != like_leaf.dtype:
            raise ValueError(f"keys of type {like_leaf.dtype} expected, {key.dtype} restored")
        return key

    return jax.tree.map(back, tree, like)


def _check_like(restored: Any, abstract: Any) -> None:
    """``ValueError`` naming the first array whose saved shape or dtype is not the one this
    run expects (a checkpoint of another env, network or jaxnav version)."""
    saved = jax.tree_util.tree_flatten_with_path(restored)[0]
    for (path, got), want in zip(saved, jax.tree.leaves(abstract), strict=True):
        if got.shape != want.shape or got.dtype != want.dtype:
            raise ValueError(
                f"{jax.tree_util.keystr(path)} was saved as {got.dtype}{list(got.shape)}, this "
                f"run expects {want.dtype}{list(want.shape)} (a checkpoint of another env, "
                "network or jaxnav version)"
            )


class Checkpoints:
    """``save(logs_done, state, metrics, meta)`` / ``restore(like_state, like_metrics)``.

    ``state`` is the (seed-batched) training state; ``metrics`` maps names to arrays
    [num_seeds, num_logs] of which the first ``logs_done`` columns are filled; ``meta`` is a
    small JSON-able dict (wall times, which do not affect the results).
    """

    def __init__(self, directory: Path, keep: int, writer: bool = True):
        """``writer=False``: restore only (the other processes of a run over several hosts,
        which read the directory process 0 writes; each manager is its process's own)."""
        self.directory = directory.absolute()
        if writer:  # orbax creates it only without ``active_processes``
            self.directory.mkdir(parents=True, exist_ok=True)
        self.manager = ocp.CheckpointManager(
            self.directory,
            options=ocp.CheckpointManagerOptions(
                max_to_keep=keep,
                create=False,
                cleanup_tmp_directories=writer,  # a save cut by a crash
                enable_async_checkpointing=False,  # saved before the next chunk starts
                multiprocessing_options=this_process_only(),
            ),
        )

    def latest(self) -> int | None:
        """Logging intervals done at the newest complete checkpoint (``None`` if none)."""
        return self.manager.latest_step()

    def save(self, logs_done: int, state: Any, metrics: dict[str, Any], meta: dict) -> None:
        arrays = {"state": _to_disk(jax.device_get(state)), "metrics": metrics}
        self.manager.save(
            logs_done,
            args=ocp.args.Composite(
                arrays=ocp.args.StandardSave(arrays), meta=ocp.args.JsonSave(meta)
            ),
        )
        self.manager.wait_until_finished()

    def restore(self, like_state: Any, like_metrics: dict[str, Any]) -> tuple[int, Any, dict, dict]:
        """``(logs_done, state, metrics, meta)`` of the newest checkpoint; the ``like_*``
        arguments give structure, shapes and dtypes (abstract values are fine)."""
        step = self.latest()
        if step is None:
            raise FileNotFoundError(f"{self.directory}: no checkpoint")
        abstract = jax.tree.map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype),
            {"state": _disk_like(like_state), "metrics": like_metrics},
        )
        restored = self.manager.restore(
            step,
            args=ocp.args.Composite(
                arrays=ocp.args.StandardRestore(abstract), meta=ocp.args.JsonRestore()
            ),
        )
        arrays = restored["arrays"]
        _check_like(arrays, abstract)  # orbax restores what was saved, whatever the target
        state = _from_disk(arrays["state"], like_state)
        metrics = {k: np.array(arrays["metrics"][k]) for k in like_metrics}  # keep the order
        return step, state, metrics, restored["meta"]

    def close(self) -> None:
        self.manager.close()
