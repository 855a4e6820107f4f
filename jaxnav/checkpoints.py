"""Checkpoints of an unfinished training run: every seed's full ``TrainState`` (params,
optimizer state, the algorithm's own such as a target network and replay buffer, env states,
RNG keys, hyperparameters, divergence flags) and the metrics of the logging intervals done
so far, so a resumed run continues bitwise where the saved one stopped.

One orbax ``CheckpointManager`` directory; the step number is the count of logging intervals
done. Orbax writes each checkpoint to a temporary directory and renames it when complete, so a
crash mid-save leaves the previous checkpoints intact (and the half-written one is ignored and
cleaned up on the next open).

Each checkpoint carries ``jaxnav_checksums.json``: the SHA-256 of every file orbax wrote and
of the inputs the state depends on (the run's config.json and maze file). A resume verifies
them and starts from the newest intact checkpoint (``newest_intact``): a flipped byte would
otherwise restore as a different Adam moment without a word.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable, Sequence
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


MANIFEST = "jaxnav_checksums.json"


def sha256_of(path: Path) -> str:
    """Hex SHA-256 of the file at ``path``."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _file_sums(step_dir: Path) -> dict[str, str]:
    return {
        str(p.relative_to(step_dir)): sha256_of(p)
        for p in sorted(step_dir.rglob("*"))
        if p.is_file() and p.name != MANIFEST
    }


def write_manifest(directory: Path, inputs: dict[str, str] | None = None) -> None:
    """Write ``MANIFEST`` in the orbax checkpoint ``directory``: the SHA-256 of every file in
    it and ``inputs`` (name to SHA-256 of the files its state depends on)."""
    manifest = {"files": _file_sums(directory), "inputs": dict(inputs or {})}
    # not safe_io.atomic_output: a temporary file left by a failed write marks it damaged
    tmp = directory / (MANIFEST + ".tmp")
    tmp.write_text(json.dumps(manifest, indent=1) + "\n")
    os.replace(tmp, directory / MANIFEST)


def manifest_damage(directory: Path) -> str | None:
    """What is wrong with the checkpoint ``directory`` (None: intact, or saved before
    checksums): a file missing, added or differing from its checksum in ``MANIFEST``."""
    try:
        manifest = json.loads((directory / MANIFEST).read_text())
        want = manifest["files"]
        if not isinstance(want, dict):
            raise TypeError("no list of files")
    except FileNotFoundError:
        return None if not (directory / (MANIFEST + ".tmp")).exists() else "no checksums"
    except (OSError, ValueError, KeyError, TypeError) as e:
        return f"unreadable checksums ({e})"
    got = _file_sums(directory)
    for name in sorted(set(want) | set(got)):
        if want.get(name) != got.get(name):
            what = "missing" if name not in got else "unexpected" if name not in want else ""
            return f"{name} {what or 'differs from its checksum'}"
    return None


class Checkpoints:
    """``save(logs_done, state, metrics, meta)`` / ``restore(like_state, like_metrics)``.

    ``state`` is the (seed-batched) training state; ``metrics`` maps names to arrays
    [num_seeds, num_logs] of which the first ``logs_done`` columns are filled; ``meta`` is a
    small JSON-able dict (wall times, which do not affect the results).
    """

    def __init__(
        self,
        directory: Path,
        keep: int,
        writer: bool = True,
        inputs: dict[str, str] | None = None,
    ):
        """``writer=False``: restore only (the other processes of a run over several hosts,
        which read the directory process 0 writes; each manager is its process's own).
        ``inputs``: checksums (name to SHA-256) of the files the state depends on, saved with
        each checkpoint and compared on resume."""
        self.directory = directory.absolute()
        self.writer, self.inputs = writer, dict(inputs or {})
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
        write_manifest(self.directory / str(logs_done), self.inputs)

    def damage(self, step: int) -> str | None:
        """What is wrong with checkpoint ``step`` (None: intact, or saved before checksums):
        a file missing, added or differing from its checksum."""
        return manifest_damage(self.directory / str(step))

    def changed_inputs(self, step: int) -> list[str]:
        """The inputs (config.json, maze file) whose checksum differs from the one saved with
        checkpoint ``step``."""
        try:
            saved = json.loads((self.directory / str(step) / MANIFEST).read_text())["inputs"]
        except (OSError, ValueError, KeyError, TypeError):
            return []
        return [k for k in sorted(self.inputs) if k in saved and saved[k] != self.inputs[k]]

    def newest_intact(self, warn: Callable[[str], None]) -> int | None:
        """The newest checkpoint whose files match their checksums (``None``: no checkpoint);
        damaged newer ones are deleted (by the writer) after ``warn`` has been told, one line.
        ``ValueError`` when none is intact, or when an input changed since it was saved (the
        state would not continue the same run)."""
        steps = sorted(self.manager.all_steps(), reverse=True)
        damaged = []
        for step in steps:
            problem = self.damage(step)
            if problem is not None:
                damaged.append(f"checkpoint {step} is damaged ({problem})")
                continue
            changed = self.changed_inputs(step)
            if changed:
                raise ValueError(
                    f"{self.directory}: {', '.join(changed)} changed since checkpoint {step} "
                    "was saved; restore the original to resume this run"
                )
            if damaged:
                warn(f"{'; '.join(damaged)}; resuming from checkpoint {step}")
                if self.writer:
                    for bad in steps[: len(damaged)]:
                        shutil.rmtree(self.directory / str(bad))
                    self.manager.reload()
            return step
        if damaged:
            raise ValueError(f"{self.directory}: no intact checkpoint: {'; '.join(damaged)}")
        return None

    def restore(
        self,
        like_state: Any,
        like_metrics: dict[str, Any],
        step: int | None = None,
        legacy: Sequence[tuple[Any, Callable[[Any], Any]]] = (),
    ) -> tuple[int, Any, dict, dict]:
        """``(logs_done, state, metrics, meta)`` of checkpoint ``step`` (default: the newest);
        the ``like_*`` arguments give structure, shapes and dtypes (abstract values are
        fine). ``legacy``: ``(like, upgrade)`` of each earlier structure a state may have been
        saved in, tried in turn where the checkpoint's is not ``like_state``'s; ``upgrade``
        turns it into one like ``like_state``."""
        step = self.latest() if step is None else step
        if step is None:
            raise FileNotFoundError(f"{self.directory}: no checkpoint")
        try:
            arrays, meta, abstract = self._read(step, like_state, like_metrics)
            upgrade = None
        except ValueError as error:  # orbax's, for another tree structure
            for like_state, upgrade in legacy:  # noqa: B007 (the one that reads is kept)
                try:
                    arrays, meta, abstract = self._read(step, like_state, like_metrics)
                    break
                except ValueError:
                    continue
            else:
                raise error from None  # in no layout: what differs from today's
        _check_like(arrays, abstract)  # orbax restores what was saved, whatever the target
        state = _from_disk(arrays["state"], like_state)
        metrics = {k: np.array(arrays["metrics"][k]) for k in like_metrics}  # keep the order
        return step, state if upgrade is None else upgrade(state), metrics, meta

    def _read(self, step: int, like_state: Any, like_metrics: dict[str, Any]) -> tuple:
        """``(arrays, meta, abstract)`` of checkpoint ``step`` restored in the structure of
        ``like_state`` and ``like_metrics`` (``abstract``: their shapes and dtypes)."""
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
        return restored["arrays"], restored["meta"], abstract

    def close(self) -> None:
        self.manager.close()
