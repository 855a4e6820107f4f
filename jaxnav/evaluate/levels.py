"""SFL's evaluation protocol (Rutherford et al. 2024): success on many held-out levels and the
conditional value at risk (CVaR) of the per-level success, the mean over the worst levels.

Picking the worst levels and measuring them on the same episodes biases CVaR low: a level
with an unlucky run of episodes is both picked and measured on that run. SFL's protocol picks
the worst ``ceil(alpha * L)`` of the L levels on one evaluation key (key A) and measures their
success on a second, independent key (key B). ``cvar_two_key`` computes it from two per-level
success tables; ``sfl_summary`` from the per-episode outcomes of both keys
(``run_level_episodes``), with the success rate over all episodes of both keys.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.environment import Environment, EnvParams
from jaxnav.evaluate import Policy, maze_success, play

CVAR_ALPHAS = (0.1, 0.01)  # SFL's CVaR-10% and CVaR-1%


def worst_levels(success: np.ndarray, alpha: float) -> np.ndarray:
    """int[ceil(alpha * L)] the indices of the lowest of the L per-level success rates
    ``success``; among equal rates the lower level index first (levels are drawn i.i.d., so
    the tie order is independent of any measurement)."""
    x = np.asarray(success, float)
    if x.ndim != 1 or len(x) == 0 or np.isnan(x).any():
        raise ValueError(f"success: need a non-empty 1-D table of rates, got shape {x.shape}")
    if not 0 < alpha <= 1:
        raise ValueError(f"alpha={alpha!r}: must be in (0, 1]")
    return np.argsort(x, kind="stable")[: math.ceil(alpha * len(x))]


def cvar_two_key(select: np.ndarray, measure: np.ndarray, alpha: float) -> float:
    """CVaR-``alpha`` of per-level success: the mean of ``measure`` (key B's rates) over the
    worst ``ceil(alpha * L)`` levels of ``select`` (key A's rates, the same L levels)."""
    select, measure = np.asarray(select, float), np.asarray(measure, float)
    if select.shape != measure.shape:
        raise ValueError(f"select {select.shape} and measure {measure.shape}: need the same levels")
    return float(measure[worst_levels(select, alpha)].mean())


def level_success(episodes: dict[str, Any], num_levels: int) -> np.ndarray:
    """float[num_levels] each level's success rate over its episodes (``episodes["layout"]``);
    ``ValueError`` if a level has none."""
    rates, counts = maze_success(episodes)
    if len(counts) > num_levels:
        raise ValueError(f"episodes reach level {len(counts) - 1}; only {num_levels} levels")
    if len(counts) < num_levels or np.min(counts) == 0:
        raise ValueError(f"every one of the {num_levels} levels needs episodes")
    return rates


def sfl_summary(
    key_a: dict[str, Any],
    key_b: dict[str, Any],
    num_levels: int,
    alphas: Sequence[float] = CVAR_ALPHAS,
) -> dict[str, Any]:
    """SFL's numbers from the per-episode outcomes (``success``, ``collision``, ``timeout``,
    ``layout``) of two independent keys over the same ``num_levels`` levels.

    ``success_rate``, ``collision_rate``, ``timeout_rate``: over all episodes of both keys;
    ``success_rate_a`` / ``_b`` per key; ``cvar_<percent>``: ``cvar_two_key`` (worst levels
    picked on A, measured on B); ``cvar_<percent>_same_key``: picked and measured on B, the
    biased figure, for comparison.
    """
    rate_a, rate_b = level_success(key_a, num_levels), level_success(key_b, num_levels)
    both = {k: np.concatenate([np.asarray(key_a[k]), np.asarray(key_b[k])]) for k in key_a}
    out: dict[str, Any] = {
        "levels": num_levels,
        "episodes": int(len(both["success"])),
        "success_rate": float(np.mean(both["success"])),
        "success_rate_a": float(np.mean(key_a["success"])),
        "success_rate_b": float(np.mean(key_b["success"])),
        "collision_rate": float(np.mean(both["collision"])),
        "timeout_rate": float(np.mean(both["timeout"])),
    }
    for alpha in alphas:
        name = f"cvar_{100 * alpha:g}"
        out[name] = cvar_two_key(rate_a, rate_b, alpha)
        out[f"{name}_same_key"] = cvar_two_key(rate_b, rate_b, alpha)
    return out


def run_level_episodes(
    env: Environment,
    params: EnvParams,
    policy: Policy,
    key: jax.Array,
    levels: jax.Array,
    episodes_per_level: int,
    max_steps: int,
) -> dict[str, jax.Array]:
    """``episodes_per_level`` episodes in each of the bank levels ``levels`` (int32[n]),
    round-robin (episode j in ``levels[j % n]``); per-episode outcomes as ``play``'s.

    Episode ``r`` of level ``l`` starts from a key of its own, ``fold_in(fold_in(key, l), r)``,
    so its start, goal and heading do not depend on which other levels share the call (the
    levels can be evaluated in chunks). A greedy policy's episodes are then fixed too; a
    random policy's actions come from the call's key.
    """
    levels = jnp.asarray(levels, jnp.int32)
    layouts = jnp.tile(levels, episodes_per_level)
    repeats = jnp.repeat(jnp.arange(episodes_per_level, dtype=jnp.int32), levels.shape[0])
    k_reset, k_play = jax.random.split(key)
    keys = jax.vmap(lambda level, r: jax.random.fold_in(jax.random.fold_in(k_reset, level), r))(
        layouts, repeats
    )
    obs, state = jax.vmap(env.reset_layout, in_axes=(0, None, 0))(keys, params, layouts)
    k_play = jax.random.fold_in(k_play, levels[0])
    return play(env, params, policy, k_play, obs, state, max_steps)
