"""Vectorized evaluation of a policy over fresh episodes."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav.environment import Environment, EnvParams

if TYPE_CHECKING:
    from jaxnav.train import Trainer

Policy = Callable[[jax.Array, jax.Array], jax.Array]  # (key, obs[N, D]) -> action[N]


def random_policy(num_actions: int) -> Policy:
    """The paper's random agent: a uniform action every step."""
    return lambda key, obs: jax.random.randint(key, obs.shape[:1], 0, num_actions)


def run_episodes(
    env: Environment,
    params: EnvParams,
    policy: Policy,
    key: jax.Array,
    num_episodes: int,
    max_steps: int,
) -> dict[str, jax.Array]:
    """Play one episode in each of ``num_episodes`` envs for at most ``max_steps`` steps (at
    least the env's time limit); per-episode outcomes.

    The episodes are fixed by ``key`` (the same key gives every agent the same test suite).
    """
    k_reset, k_run = jax.random.split(key)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(
        jax.random.split(k_reset, num_episodes), params
    )
    shortest = getattr(state, "shortest_path", jnp.full(num_episodes, -1, jnp.int32))
    zeros = jnp.zeros(num_episodes)
    false = jnp.zeros(num_episodes, bool)
    init = (obs, state, false, zeros, zeros, false, false, false)

    def step(carry, key):
        obs, state, ended, ret, steps, success, collision, timeout = carry
        k_pol, k_env = jax.random.split(key)
        action = policy(k_pol, obs)
        obs, state, reward, terminated, truncated, info = jax.vmap(
            env.step, in_axes=(0, 0, 0, None)
        )(jax.random.split(k_env, num_episodes), state, action, params)
        live = ~ended
        ret = ret + jnp.where(live, reward, 0.0)
        steps = steps + live
        success = success | (live & info["goal_reached"])
        collision = collision | (live & info["collision"])
        timeout = timeout | (live & truncated)
        ended = ended | terminated | truncated
        return (obs, state, ended, ret, steps, success, collision, timeout), None

    keys = jax.random.split(k_run, max_steps)
    carry, _ = jax.lax.scan(step, init, keys)
    _, _, _, ret, steps, success, collision, timeout = carry
    return {
        "return": ret,
        "steps": steps,
        "success": success,
        "collision": collision,
        "timeout": timeout,
        "shortest_path": shortest,
    }


def summarize(episodes: dict[str, jax.Array]) -> dict[str, float]:
    """Rates over all episodes; steps and path ratio over successful ones."""
    success = episodes["success"]
    n_success = jnp.maximum(success.sum(), 1)
    ratio = episodes["steps"] / jnp.maximum(episodes["shortest_path"], 1)
    has_path = episodes["shortest_path"] > 0
    n_ratio = jnp.maximum((success & has_path).sum(), 1)
    out = {
        "episodes": success.shape[0],
        "success_rate": success.mean(),
        "collision_rate": episodes["collision"].mean(),
        "timeout_rate": episodes["timeout"].mean(),
        "mean_return": episodes["return"].mean(),
        "mean_steps": jnp.where(success, episodes["steps"], 0).sum() / n_success,
        "mean_path_ratio": jnp.where(success & has_path, ratio, 0).sum() / n_ratio,
    }
    return {k: float(v) for k, v in out.items()}


def evaluate(
    env: Environment, params: EnvParams, policy: Policy, key: jax.Array, num_episodes: int
) -> dict[str, float]:
    """Summary metrics of ``policy`` on ``num_episodes`` fresh episodes."""
    run = jax.jit(run_episodes, static_argnums=(0, 2, 4, 5))
    max_steps = int(params.max_steps_in_episode)
    return summarize(run(env, params, policy, key, num_episodes, max_steps))


def evaluate_seeds(
    trainer: Trainer, params: Any, episodes: int, seed: int, policy: str = "trained"
) -> list[dict[str, float]]:
    """Greedy (or random) evaluation of each seed's parameters on the same fresh episodes."""
    env, env_params = trainer.env, trainer.env_params
    key = jax.random.key(seed)
    max_steps = int(env_params.max_steps_in_episode)

    def one(p):
        pol = trainer.greedy_policy(p) if policy == "trained" else random_policy(env.num_actions)
        return run_episodes(env, env_params, pol, key, episodes, max_steps)

    out = jax.jit(jax.vmap(one))(params)
    n = jax.tree.leaves(params)[0].shape[0]
    return [summarize(jax.tree.map(lambda x, i=i: x[i], out)) for i in range(n)]


def mean_of(rows: Sequence[dict[str, float]]) -> dict[str, float]:
    return {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}


if __name__ == "__main__":
    import sys

    from jaxnav.cli import evaluate_main

    sys.exit(evaluate_main())
