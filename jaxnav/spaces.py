"""Action and observation spaces (the subset of gymnax's that trainers use)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp


class Discrete:
    """Integers ``0 .. n-1``."""

    def __init__(self, n: int, dtype: Any = jnp.int32):
        self.n = int(n)
        self.shape: tuple[int, ...] = ()
        self.dtype = dtype

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.randint(key, self.shape, 0, self.n).astype(self.dtype)

    def contains(self, x: jax.Array) -> jax.Array:
        x = jnp.asarray(x)
        return jnp.logical_and(x >= 0, x < self.n) & (jnp.floor(x) == x)

    def __repr__(self) -> str:
        return f"Discrete({self.n})"


class Box:
    """Vectors (float or integer ``dtype``) with elementwise bounds."""

    def __init__(self, low: Any, high: Any, shape: tuple[int, ...], dtype: Any = jnp.float32):
        self.low = low
        self.high = high
        self.shape = tuple(shape)
        self.dtype = dtype

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.uniform(key, self.shape, minval=self.low, maxval=self.high).astype(
            self.dtype
        )

    def contains(self, x: jax.Array) -> jax.Array:
        x = jnp.asarray(x)
        if x.shape != self.shape:
            return jnp.asarray(False)
        return jnp.all(jnp.isfinite(x) & (x >= self.low) & (x <= self.high))

    def __repr__(self) -> str:
        return f"Box(low={self.low}, high={self.high}, shape={self.shape})"
