"""The whole pipeline learns: a short training run on a small grid must beat the random agent."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from conftest import assert_learned_the_maze, run_sharded

import jaxnav
from jaxnav.config import TrainConfig
from jaxnav.evaluate import run_episodes
from jaxnav.experiments import HELD_OUT_MAZE_SEED
from jaxnav.train import Trainer


@pytest.mark.slow
@pytest.mark.parametrize("devices", [1, 2], ids=["one-device", "envs-on-two-devices"])
def test_dueling_double_dqn_learns_a_small_maze(devices):
    """The same bar with the envs split over two devices (gradients averaged across them)."""
    config = TrainConfig(
        devices=devices,
        env_kwargs={"size": 7, "max_steps": 30},
        hidden_sizes=(128, 128),
        total_timesteps=48_000,
        num_envs=16,
        learning_starts=2_000,
        buffer_size=20_000,
        batch_size=64,
        replay_ratio=4.0,  # one gradient step of 64 per step of the 16 envs
        target_update_period=500,
        eps_decay_steps=24_000,
        log_interval=8_000,
    )
    trainer = Trainer(config)
    if devices == 1:
        state, metrics = jax.jit(trainer.train)(jax.random.key(0))
    else:
        state, metrics = run_sharded(trainer, jax.random.key(0)[None])
        state, metrics = jax.tree.map(lambda x: x[0], (jax.device_get(state), metrics))
    assert_learned_the_maze(trainer, state.params, metrics, 0.9)


# RobotJaxNav-v0's map-free robot at a CPU's scale (docs/mapfree.md gives the command)
MAPFREE_CPU = {
    "num_envs": 256,
    "rollout_length": 16,
    "num_minibatches": 8,
    "num_epochs": 2,
    "hidden_sizes": (256, 256),
    "compute_dtype": "float32",
    "fused_layer_norm": False,
    "total_timesteps": 1_048_576,
    "log_interval": 262_144,
    "gamma": 0.99,
    "td_lambda": 0.9,
    "eps_decay_steps": 262_144,
}


@pytest.mark.slow
def test_the_map_free_robot_learns_jaxnav_levels_on_a_cpu():
    """Map-free (lidar, goal distance and bearing, previous action, radius), robots of 0.1-0.25
    m: 1M env steps lift greedy success on held-out levels at JaxNav's 0.25 m far above the
    random agent's (about 0.02)."""
    env_kwargs = {"num_layouts": 256, "radius_range": (0.1, 0.25)}
    config = TrainConfig.for_env(
        "RobotJaxNav-v0", algo="pqn", env_kwargs=env_kwargs, eval_episodes=0, **MAPFREE_CPU
    )
    trainer = Trainer(config)
    state, _ = jax.jit(trainer.train)(jax.random.key(0))
    env, params = jaxnav.make("RobotJaxNav-v0", num_layouts=200, maze_seed=HELD_OUT_MAZE_SEED)
    policy = trainer.greedy_policy(state.params)
    out = run_episodes(env, params, policy, jax.random.key(1), 400, params.max_steps_in_episode)
    assert float(np.mean(out["success"])) >= 0.4
