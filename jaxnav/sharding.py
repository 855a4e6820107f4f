"""Where a training run's arrays live: a (seeds x envs) mesh over the devices of one or more hosts.

Seeds are independent, so they are split across devices first (no communication at all). What
is left of the device count splits each seed's environments and their replay columns; each
gradient batch is split over the same devices and XLA sums the parts of the gradient.
Parameters, optimizer state and RNG keys are replicated across a seed's devices.

``Trainer.sharded`` jits the one-device program with these layouts and XLA partitions it
(GSPMD), so a sharded run computes what one device does, up to the order of floating-point
sums. (``shard_map`` with hand-written collectives was the first version; XLA's GPU compiler
crashed on MJX inside it.) Several hosts are the same mesh over ``jax.devices()`` after
``jax.distributed.initialize``.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

SEEDS, ENVS = "seeds", "envs"


def mesh_shape(num_seeds: int, devices: int) -> tuple[int, int]:
    """``(seed shards, env shards)``: as many devices as possible go to seeds."""
    seed_shards = math.gcd(num_seeds, devices)
    return seed_shards, devices // seed_shards


def make_mesh(num_seeds: int, devices: int) -> Mesh:
    """The first ``devices`` devices (of every host) as a (seeds x envs) mesh."""
    grid = np.array(jax.devices()[:devices]).reshape(mesh_shape(num_seeds, devices))
    return Mesh(grid, (SEEDS, ENVS))


def state_specs(state: Any, algo_specs: Any) -> Any:
    """``PartitionSpec``s of a seed-batched ``TrainState`` (arrays or abstract values), given
    ``algo_specs``, those of its ``algo_state`` (the algorithm's: e.g. a replay buffer's
    arrays are [seed, time, env, ...]).

    Per-env fields have the env axis after the seed axis; everything else (parameters,
    optimizer, keys, counters, a curriculum's per-layout statistics) is per seed only.
    """
    per_env = P(SEEDS, ENVS)
    specs = jax.tree.map(lambda _: P(SEEDS), state)
    return specs.replace(
        algo_state=algo_specs,
        env_state=jax.tree.map(lambda _: per_env, state.env_state),
        obs=per_env,
        episode_return=per_env,
        episode_length=per_env,
        memory=None if state.memory is None else per_env,
    )


def shardings(mesh: Mesh, specs: Any) -> Any:
    return jax.tree.map(lambda s: NamedSharding(mesh, s), specs, is_leaf=_is_spec)


def place(tree: Any, mesh: Mesh, specs: Any) -> Any:
    """Host (numpy) arrays, the same on every host, as global arrays laid out by ``specs``."""

    def one(x: Any, spec: P) -> jax.Array:
        if is_key(x):
            data = one(jax.random.key_data(x), P(*spec, None))
            return jax.random.wrap_key_data(data, impl=jax.random.key_impl(x))
        x = np.asarray(x)
        sharding = NamedSharding(mesh, spec)
        return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])

    return jax.tree.map(one, tree, specs, is_leaf=_is_spec)


def to_host(tree: Any) -> Any:
    """Global arrays as numpy arrays on every host (gathered across hosts when there are
    several; typed PRNG keys stay keys)."""
    if jax.process_count() == 1:
        return jax.device_get(tree)

    def one(x: jax.Array) -> Any:
        if is_key(x):
            data = multihost_utils.process_allgather(jax.random.key_data(x), tiled=True)
            return jax.random.wrap_key_data(data, impl=jax.random.key_impl(x))
        return multihost_utils.process_allgather(x, tiled=True)

    return jax.tree.map(one, tree)


def is_key(x: Any) -> bool:
    """A typed PRNG key array (stored and moved as its raw ``key_data`` words)."""
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _is_spec(x: Any) -> bool:
    return isinstance(x, P)
