"""How the training program is laid out for the backend it runs on: the choices that make it
fast on a GPU and keep it short to compile on a CPU. They change how XLA schedules the same
operations, never the values computed. The trainer resolves them once (``layout``) and hands
them to the algorithm (``algos.base.ProgramLayout``, ``Loop.layout``), which queries no
backend itself."""

from __future__ import annotations

import jax

from jaxnav.algos.base import ProgramLayout


def layout(gpu_updates_unroll: int, platform: str | None = None) -> ProgramLayout:
    """The layout of a training program on ``platform`` (JAX's default backend where None)
    for an algorithm whose gradient-step loops run ``gpu_updates_unroll`` steps a trip on a
    GPU (``Algorithm.gpu_updates_unroll``)."""
    platform = jax.default_backend() if platform is None else platform
    return ProgramLayout(
        updates_unroll=updates_unroll(gpu_updates_unroll, platform),
        returns_unrolled=returns_unrolled(platform),
        target_update_select=target_update_select(platform),
        optimizer_barrier=optimizer_barrier(platform),
    )


def updates_unroll(gpu_unroll: int, platform: str) -> int:
    """How many gradient steps one trip of a loop runs (at most its steps), so that XLA
    schedules across steps: on a GPU up to the algorithm's ``gpu_unroll`` (PQN 16 of an
    epoch's minibatches, the DQN 2 of its updates; measured: docs/performance.md); on a CPU
    1, where the loop costs nothing to speak of and compiles stay short."""
    return gpu_unroll if platform == "gpu" else 1


def returns_unrolled(platform: str) -> bool:
    """Whether PQN's lambda-returns run as straight-line code (``pqn.lambda_returns``'s
    ``unrolled``): on a GPU, where each trip of the loop costs a round trip to the host, at
    no measurable cost in compile time; on a CPU the loop, whose trips cost nothing to speak
    of. The rollout's own loop stays rolled: unrolling it saved little and cost seconds of
    compile (docs/performance.md)."""
    return platform == "gpu"


def target_update_select(platform: str) -> bool:
    """Whether the DQN's target update is a select over the parameters, as on a GPU, where
    a cond every gradient step cost more (docs/performance.md); on a CPU the cond skips the
    parameter-sized work."""
    return platform != "cpu"


def optimizer_barrier(platform: str) -> bool:
    """Whether the flat gradient is written out once before the optimizer reads it: on a
    GPU, where otherwise the clip's norm and Adam's moments each read the layers' gradients
    through the concatenation, the norm slowly."""
    return platform == "gpu"
