"""What the base class declares for the layers above, on every kind of env: ``step_no_reset``
is ``step`` before its auto-reset, ``reset_to(*reset_to_args(state))`` restarts a fresh
episode exactly, ``layouts_from`` drops the first layouts, ``scene`` describes an episode."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav
from jaxnav.environment import Environment

ENVS = [
    ("GridMaze-v0", {}),
    ("GridMaze-Random-v0", {"num_layouts": 8}),
    ("RobotRandom-v0", {"backend": "kinematic", "num_layouts": 4, "max_steps": 10}),
]


@pytest.mark.parametrize("env_id, kwargs", ENVS)
def test_step_no_reset_is_step_before_its_auto_reset(env_id, kwargs):
    env, params = jaxnav.make(env_id, **kwargs)
    n = 64
    keys = jax.random.split(jax.random.key(1), n)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    no_reset = jax.jit(jax.vmap(env.step_no_reset, in_axes=(0, 0, 0, None)))
    ended = np.zeros(n, bool)
    for t in range(12):
        keys = jax.random.split(jax.random.key(100 + t), n)
        action = jax.random.randint(jax.random.key(200 + t), (n,), 0, env.num_actions)
        obs, next_state, *flags, info = step(keys, state, action, params)
        obs1, state1, *flags1, info1 = no_reset(keys, state, action, params)
        chex.assert_trees_all_equal(flags1, flags)  # reward, terminated, truncated
        chex.assert_trees_all_equal(obs1, info["final_observation"])
        assert info1.keys() == info.keys() - {"final_observation"}
        live = ~np.asarray(flags[1] | flags[2])  # no reset happened there
        ended |= ~live
        chex.assert_trees_all_equal(
            jax.tree.map(lambda x, live=live: x[live], (obs1, state1)),
            jax.tree.map(lambda x, live=live: x[live], (obs, next_state)),
        )
        state = next_state
    assert ended.any()  # the steps crossed episode ends, where only ``step`` resets


@pytest.mark.parametrize("env_id, kwargs", ENVS)
def test_reset_to_its_args_restarts_a_fresh_episode(env_id, kwargs):
    env, params = jaxnav.make(env_id, **kwargs)
    keys = jax.random.split(jax.random.key(3), 16)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    args = jax.vmap(env.reset_to_args)(state)
    obs2, state2 = jax.vmap(env.reset_to, in_axes=(0, None, 0, 0, 0))(keys, params, *args)
    chex.assert_trees_all_equal((obs2, state2), (obs, state))


@pytest.mark.parametrize("env_id, kwargs", ENVS[1:])
def test_layouts_from_keeps_the_later_layouts(env_id, kwargs):
    env, params = jaxnav.make(env_id, **kwargs)
    later = env.layouts_from(params, 3)
    assert env.num_layouts(later) == env.num_layouts(params) - 3
    _, state = env.reset_layout(jax.random.key(0), later, jnp.int32(0))
    _, state3 = env.reset_layout(jax.random.key(0), params, jnp.int32(3))
    chex.assert_trees_all_equal(env.reset_to_args(state)[:2], env.reset_to_args(state3)[:2])


def test_one_layout_env_has_no_later_layouts():
    env, params = jaxnav.make("GridMaze-v0")
    assert Environment.layouts_from(env, params, 0) is params
    with pytest.raises(ValueError, match="no layouts after 0"):
        Environment.layouts_from(env, params, 1)


@pytest.mark.parametrize("env_id, kwargs", ENVS)
def test_scene_describes_an_episode(env_id, kwargs):
    env, params = jaxnav.make(env_id, **kwargs)
    _, s0 = env.reset(jax.random.key(0), params)
    _, s1, *_ = env.step_no_reset(jax.random.key(1), s0, jnp.int32(0), params)
    states = jax.tree.map(lambda a, b: np.stack([a, b]), s0, s1)  # an episode's first 2
    ranges = np.stack([env.sensor_ranges(s, params) for s in (s0, s1)])
    scene = env.scene(params, states, ranges)
    assert list(scene) == [
        "xy", "heading", "lasers", "laser_angles", "goal", "walls", "arena", "goal_radius",
        "radius",
    ]  # fmt: skip
    assert scene["xy"].shape == (2, 2) and scene["heading"].shape == (2,)
    assert scene["lasers"].shape == (2, len(scene["laser_angles"]))
    assert scene["walls"].ndim == 2 and scene["walls"].shape[1] == 4
    width, height = scene["arena"]
    assert ((scene["xy"] > 0) & (scene["xy"] < [width, height])).all()
