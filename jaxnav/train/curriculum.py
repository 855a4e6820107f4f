"""A curriculum over the env's bank of layouts by learnability (``--curriculum learnability``).

Sampling for learnability (SFL, Rutherford et al. 2024) trains on the levels the policy solves
sometimes: a level it always solves or never solves teaches it little. Here the training state
keeps, per bank layout, the success of the episodes that ended there (``LayoutStats``), and
fresh episodes draw their layout with probability ``UNIFORM_SHARE / L`` plus ``1 -
UNIFORM_SHARE`` times the layout's share of the learnability ``p (1 - p)`` summed over the
bank, ``p`` its success. The uniform share keeps every layout tried, so a layout whose
estimate says 0 or 1 is seen again as the policy changes. A layout starts at ``p = PRIOR``
(the most learnable), so layouts not yet played are drawn first.

The statistics are arrays of the training state (``TrainState.curriculum``), so checkpoints
and ``--resume`` carry them; the env draws the layouts (``EnvParams.layout_cdf``,
``Environment.weighted_layouts``), the loop knows no maze.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

# the share of fresh episodes whose layout is drawn uniformly, the rest by learnability
UNIFORM_SHARE = 0.5
# each ended episode moves its layout's success this far towards its outcome: an average
# over about the last 1 / SUCCESS_STEP episodes of the layout
SUCCESS_STEP = 0.1
# a layout's success before any episode ended there: the most learnable value
PRIOR = 0.5


@struct.dataclass
class LayoutStats:
    """Per bank layout: the exponentially averaged success of the episodes that ended there,
    float32[L], and how many ended there, int32[L]."""

    success: jax.Array
    episodes: jax.Array


def init(num_layouts: int) -> LayoutStats:
    """The statistics of a bank of ``num_layouts`` before any episode ended."""
    return LayoutStats(
        success=jnp.full((num_layouts,), PRIOR, jnp.float32),
        episodes=jnp.zeros((num_layouts,), jnp.int32),
    )


def update(
    stats: LayoutStats, layout: jax.Array, ended: jax.Array, reached: jax.Array
) -> LayoutStats:
    """``stats`` after the steps of ``layout`` (the layout each step ran in, int32), ``ended``
    (whether the step ended its episode) and ``reached`` (whether it reached the goal), arrays
    of one shape (e.g. [time, env]): the n episodes that ended in a layout with s successes
    move its success to ``k p + (1 - k) s / n``, ``k = (1 - SUCCESS_STEP) ** n``."""
    num = stats.success.shape[0]
    flat = layout.reshape(-1)
    count = lambda x: jax.ops.segment_sum(  # noqa: E731
        x.reshape(-1).astype(jnp.int32), flat, num_segments=num
    )
    n = count(ended)
    # integer counts: exact whatever the order of the sums, so identical over devices
    s = count(ended & reached)
    keep = (1.0 - SUCCESS_STEP) ** n.astype(jnp.float32)
    mean = s.astype(jnp.float32) / jnp.maximum(n, 1).astype(jnp.float32)
    return LayoutStats(
        success=keep * stats.success + (1.0 - keep) * mean, episodes=stats.episodes + n
    )


def learnability(success: jax.Array) -> jax.Array:
    """SFL's learnability ``p (1 - p)`` of success rates ``p``: 0.25 at 0.5, 0 at 0 and 1."""
    return success * (1.0 - success)


def layout_probabilities(stats: LayoutStats) -> jax.Array:
    """float32[L]: the probability that a fresh episode draws each layout (module docstring;
    uniform where no layout is learnable at all)."""
    num = stats.success.shape[0]
    weight = learnability(stats.success)
    total = weight.sum()
    by_learnability = jnp.where(total > 0, weight / jnp.where(total > 0, total, 1.0), 1.0 / num)
    return UNIFORM_SHARE / num + (1.0 - UNIFORM_SHARE) * by_learnability


def layout_cdf(stats: LayoutStats) -> jax.Array:
    """``layout_probabilities`` cumulated, last 1: ``EnvParams.layout_cdf``."""
    cdf = jnp.cumsum(layout_probabilities(stats))
    return cdf / cdf[-1]
