"""How the training program is laid out for the backend it runs on: the choices that make it
fast on a GPU and keep it short to compile on a CPU. They change how XLA schedules the same
operations, never the values computed."""

from __future__ import annotations

import jax


def on_gpu() -> bool:
    """Whether JAX's default backend is a GPU."""
    return jax.default_backend() == "gpu"


def updates_unroll(steps: int, gpu_unroll: int) -> int:
    """How many of a loop's ``steps`` gradient steps one trip runs, so that XLA schedules
    across steps: on a GPU up to the algorithm's ``gpu_unroll`` (PQN 16 of an epoch's
    minibatches, the DQN 2 of its updates; measured: docs/performance.md); on a CPU 1, where
    the loop costs nothing to speak of and compiles stay short."""
    return min(steps, gpu_unroll) if on_gpu() else 1


def returns_unrolled() -> bool:
    """Whether PQN's lambda-returns run as straight-line code (``pqn.lambda_returns``'s
    ``unrolled``): on a GPU, where each trip of the loop costs a round trip to the host, at
    no measurable cost in compile time; on a CPU the loop, whose trips cost nothing to speak
    of. The rollout's own loop stays rolled: unrolling it saved little and cost seconds of
    compile (docs/performance.md)."""
    return on_gpu()


def target_update_select() -> bool:
    """Whether the DQN's target update is a select over the parameters, as on a GPU, where
    a cond every gradient step cost more (docs/performance.md); on a CPU the cond skips the
    parameter-sized work."""
    return jax.default_backend() != "cpu"


def optimizer_barrier() -> bool:
    """Whether the flat gradient is written out once before the optimizer reads it: on a
    GPU, where otherwise the clip's norm and Adam's moments each read the layers' gradients
    through the concatenation, the norm slowly."""
    return on_gpu()
