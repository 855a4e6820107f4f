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
    return play(env, params, policy, k_run, obs, state, max_steps)


def play(
    env: Environment,
    params: EnvParams,
    policy: Policy,
    key: jax.Array,
    obs: jax.Array,
    state: Any,
    max_steps: int,
    record: bool = False,
) -> dict[str, jax.Array]:
    """Play the episodes that start at ``(obs, state)`` (a batch, e.g. from ``env.reset_to``
    for a fixed test suite) for ``max_steps`` steps; per-episode outcomes.

    Steps without auto-reset: an ended episode's state stays as it ended, so ``record=True``
    also returns ``"states"``, the batch's states before the first step and after each one
    (leading axis ``max_steps + 1``), the final pose included.
    """
    num_episodes = obs.shape[0]
    shortest = getattr(state, "shortest_path", jnp.full(num_episodes, -1, jnp.int32))
    zeros = jnp.zeros(num_episodes)
    false = jnp.zeros(num_episodes, bool)
    init = (obs, state, false, zeros, zeros, false, false, false)
    freeze = lambda ended, old, new: jax.tree.map(  # noqa: E731
        lambda o, n: jnp.where(ended.reshape(ended.shape + (1,) * (n.ndim - 1)), o, n), old, new
    )

    def step(carry, key):
        obs, state, ended, ret, steps, success, collision, timeout = carry
        k_pol, k_env = jax.random.split(key)
        action = policy(k_pol, obs)
        new_obs, new_state, reward, terminated, info = jax.vmap(
            env.step_env, in_axes=(0, 0, 0, None)
        )(jax.random.split(k_env, num_episodes), state, action, params)
        truncated = (new_state.time >= params.max_steps_in_episode) & ~terminated
        live = ~ended
        ret = ret + jnp.where(live, reward, 0.0)
        steps = steps + live
        success = success | (live & info["goal_reached"])
        collision = collision | (live & info["collision"])
        timeout = timeout | (live & truncated)
        obs, state = freeze(ended, (obs, state), (new_obs, new_state))
        ended = ended | terminated | truncated
        carry = (obs, state, ended, ret, steps, success, collision, timeout)
        return carry, (state if record else None)

    carry, states = jax.lax.scan(step, init, jax.random.split(key, max_steps))
    _, _, _, ret, steps, success, collision, timeout = carry
    out = {
        "return": ret,
        "steps": steps,
        "success": success,
        "collision": collision,
        "timeout": timeout,
        "shortest_path": shortest,
    }
    if record:
        out["states"] = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), state, states)
    return out


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
