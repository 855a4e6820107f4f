"""Every choice that lays the program out for the backend it runs on: what makes it fast on a
GPU and keeps it short to compile on a CPU. Each changes how XLA schedules the same
operations, never the values computed. Envs, agents and the trainer ask this module; the
algorithms (``jaxnav.algos``) ask none: the trainer resolves their choices once
(``train.program_layout``) and hands them over as ``Loop.layout``
(``algos.base.ProgramLayout``).

Each function takes the ``platform`` ("cpu", "gpu", "tpu") to decide for, JAX's default
backend where None. The measurements behind the choices: docs/performance.md.
"""

from __future__ import annotations

import jax

# On a GPU, ``step_batch``'s compaction (index gathers and scatters) costs more than the resets
# it saves in batches below this size (measured against vmap(step): docs/results-history.md)
ACCELERATOR_MIN_BATCH = 2**17


def _platform(platform: str | None) -> str:
    return jax.default_backend() if platform is None else platform


def updates_unroll(gpu_unroll: int, platform: str | None = None) -> int:
    """How many gradient steps one trip of a loop runs (at most its steps), so that XLA
    schedules across steps: on a GPU up to the algorithm's ``gpu_unroll`` (PQN 16 of an
    epoch's minibatches, the DQN 2 of its updates; measured: docs/performance.md); on a CPU
    1, where the loop costs nothing to speak of and compiles stay short."""
    return gpu_unroll if _platform(platform) == "gpu" else 1


def returns_unrolled(platform: str | None = None) -> bool:
    """Whether PQN's lambda-returns run as straight-line code (``pqn.lambda_returns``'s
    ``unrolled``): on a GPU, where each trip of the loop costs a round trip to the host, at
    no measurable cost in compile time; on a CPU the loop, whose trips cost nothing to speak
    of. The rollout's own loop stays rolled: unrolling it saved little and cost seconds of
    compile (docs/performance.md)."""
    return _platform(platform) == "gpu"


def target_update_select(platform: str | None = None) -> bool:
    """Whether the DQN's target update is a select over the parameters, as on a GPU, where
    a cond every gradient step cost more (docs/performance.md); on a CPU the cond skips the
    parameter-sized work."""
    return _platform(platform) != "cpu"


def optimizer_barrier(platform: str | None = None) -> bool:
    """Whether the flat gradient is written out once before the optimizer reads it: on a
    GPU, where otherwise the clip's norm and Adam's moments each read the layers' gradients
    through the concatenation, the norm slowly."""
    return _platform(platform) == "gpu"


def masked_taken_values(platform: str | None = None) -> bool:
    """Whether the Q-value of the action taken is a masked sum (``agents.dqn.taken_values``'s
    ``masked``): on a GPU, where ``take_along_axis``'s gradient is a scatter-add into zeros,
    two more kernels a gradient step; on a CPU ``take_along_axis``, which is faster there."""
    return _platform(platform) == "gpu"


def layer_norm_kernels(platform: str | None = None) -> bool:
    """Whether the fused LayerNorm runs as Pallas kernels (``QNetwork.norm_impl`` "pallas"):
    on a GPU (docs/performance.md); elsewhere the jnp form of the same math ("fused"), a
    little faster than flax's on a CPU."""
    return _platform(platform) == "gpu"


def pallas_interpret(platform: str | None = None) -> bool:
    """Whether Pallas kernels run in Pallas's interpreter: on every backend but a GPU, which
    alone compiles them (with Triton)."""
    return _platform(platform) != "gpu"


def ray_cast_unrolled(platform: str | None = None) -> bool:
    """Whether a ray cast finds the nearest box as a chain of elementwise minimums box after
    box (``geometry.ray_box_distances``'s ``unrolled``), which XLA runs on a GPU as one
    elementwise kernel over the rays; on a CPU a reduction over the boxes, which XLA
    vectorizes over the rays there (docs/performance.md)."""
    return _platform(platform) != "cpu"


def step_batch_as_vmap(num: int, platform: str | None = None) -> bool:
    """Whether a batch of ``num`` envs steps as ``vmap(step)`` rather than through
    ``Environment.step_batch``'s compaction: on an accelerator, batches smaller than
    ``ACCELERATOR_MIN_BATCH``; on a CPU none."""
    return _platform(platform) != "cpu" and num < ACCELERATOR_MIN_BATCH
