"""GymnaxV0: the gymnax 0.0.x API on our environments, checked against gymnax and rejax."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav
from jaxnav import spaces
from jaxnav.wrappers import GymnaxV0

UP, DOWN = 0, 1
SIZE = 7


def open_maze(max_steps: int = 60):
    """A 7x7 GridMaze without obstacles, so that every move's outcome is known."""
    env, params = jaxnav.make("GridMaze-v0", size=SIZE, obstacle_density=0.0, max_steps=max_steps)
    return GymnaxV0(env), params


def robot_cell(obs: jax.Array) -> tuple[int, int]:
    """(row, col) of the robot in an ``index`` observation (GridMaze-v0's default)."""
    return int(obs[0]), int(obs[1])


def start_at(env: GymnaxV0, params, start, goal):
    return env.reset_to(jax.random.key(0), params, jnp.array(start), jnp.array(goal))


def test_step_returns_five_values_and_keeps_info():
    env, params = open_maze()
    obs, state = start_at(env, params, (3, 3), (0, 0))
    out = env.step(jax.random.key(1), state, DOWN, params)
    assert len(out) == 5
    obs2, state2, reward, done, info = out
    assert obs2.shape == obs.shape and reward.shape == () and done.shape == ()
    assert done.dtype == jnp.bool_ and not bool(done)
    assert not bool(info["terminated"]) and not bool(info["truncated"])
    assert float(info["discount"]) == 1.0
    assert robot_cell(info["final_observation"]) == (4, 3)
    assert "goal_reached" in info  # the wrapped env's own info survives


def test_done_at_termination_goal():
    env, params = open_maze()
    _, state = start_at(env, params, (1, 0), (0, 0))
    obs, state, reward, done, info = env.step(jax.random.key(1), state, UP, params)
    assert bool(done) and bool(info["terminated"]) and not bool(info["truncated"])
    assert float(reward) == 4.0 and float(info["discount"]) == 0.0
    assert robot_cell(info["final_observation"]) == (0, 0)  # last obs of the old episode
    assert int(state.time) == 0  # auto-reset


def test_done_at_termination_collision():
    env, params = open_maze()
    _, state = start_at(env, params, (0, 3), (6, 6))
    _, _, reward, done, info = env.step(jax.random.key(1), state, UP, params)  # off the grid
    assert bool(done) and bool(info["terminated"]) and not bool(info["truncated"])
    assert float(reward) == -1.0 and float(info["discount"]) == 0.0


def test_done_at_truncation():
    env, params = open_maze(max_steps=2)
    _, state = start_at(env, params, (3, 3), (0, 0))
    _, state, _, done, _ = env.step(jax.random.key(1), state, DOWN, params)
    assert not bool(done)
    obs, state, _, done, info = env.step(jax.random.key(2), state, UP, params)
    assert bool(done) and bool(info["truncated"]) and not bool(info["terminated"])
    assert float(info["discount"]) == 1.0  # a time limit is not terminal
    assert robot_cell(info["final_observation"]) == (3, 3)
    assert int(state.time) == 0


def test_jit_and_vmap():
    env, params = jaxnav.make("GridMaze-v0", size=SIZE, max_steps=5)
    env = GymnaxV0(env)
    n = 16
    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    obs, state = reset(jax.random.split(jax.random.key(0), n), params)
    assert obs.shape == (n, env.observation_space(params).shape[0])

    def body(carry, key):
        obs, state = carry
        k_act, k_step = jax.random.split(key)
        actions = jax.random.randint(k_act, (n,), 0, env.num_actions)
        obs, state, reward, done, info = step(jax.random.split(k_step, n), state, actions, params)
        return (obs, state), (done, info["terminated"], info["truncated"], reward)

    _, (done, term, trunc, reward) = jax.lax.scan(
        body, (obs, state), jax.random.split(jax.random.key(1), 20)
    )
    assert done.shape == (20, n) and done.dtype == jnp.bool_
    np.testing.assert_array_equal(done, term | trunc)
    assert bool(done.any())  # 20 steps > the 5-step time limit
    assert bool(jnp.isfinite(reward).all())


def test_attributes_fall_through():
    env, params = open_maze()
    assert env.name == "GridMaze-v0"
    assert env.num_actions == 4
    assert env.size == SIZE  # GridMaze's own attribute
    assert env.default_params.max_steps_in_episode == params.max_steps_in_episode
    assert env.unwrapped.config.size == SIZE


def test_spaces_without_gymnax(monkeypatch):
    from jaxnav import wrappers

    monkeypatch.setattr(wrappers, "gymnax_spaces", None)
    env, params = open_maze()
    assert isinstance(env.action_space(params), spaces.Discrete)
    assert isinstance(env.observation_space(params), spaces.Box)


def test_spaces_are_gymnax_instances():
    gymnax_spaces = pytest.importorskip("gymnax.environments.spaces")
    env, params = open_maze()
    action_space = env.action_space(params)
    obs_space = env.observation_space(params)
    assert isinstance(action_space, gymnax_spaces.Discrete) and action_space.n == 4
    assert isinstance(obs_space, gymnax_spaces.Box)
    assert obs_space.shape == env.unwrapped.observation_space(params).shape
    a = action_space.sample(jax.random.key(0))
    assert a.shape == () and 0 <= int(a) < 4
    obs, _ = env.reset(jax.random.key(0), params)
    assert bool(obs_space.contains(obs))


def test_rejax_dqn_trains_through_wrapper():
    rejax = pytest.importorskip("rejax")
    env, params = jaxnav.make("GridMaze-v0", size=SIZE, obs_mode="onehot")  # for rejax's MLP
    algo = rejax.DQN.create(
        env=GymnaxV0(env),
        env_params=params,
        agent="DuelingQNetwork",  # rejax 0.1.3 fixes the hidden layers at (64, 64)
        ddqn=True,
        num_envs=4,
        total_timesteps=4096,
        eval_freq=2048,
        fill_buffer=256,
        buffer_size=4096,
        batch_size=32,
        target_update_freq=64,
        polyak=0.0,
        learning_rate=1e-3,
        skip_initial_evaluation=True,
    )
    ts, (lengths, returns) = jax.jit(algo.train)(jax.random.key(0))
    leaves = jax.tree.leaves(ts.q_ts.params)
    assert leaves and all(bool(jnp.isfinite(x).all()) for x in leaves)
    assert int(ts.global_step) >= 4096
    assert lengths.shape == returns.shape == (2, 128)  # 2 evaluations of 128 episodes
    assert bool(jnp.isfinite(returns).all())
    assert bool((lengths <= params.max_steps_in_episode).all())
