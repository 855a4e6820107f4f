"""The whole pipeline learns: a short training run on a small grid must beat the random agent."""

from __future__ import annotations

import jax
import pytest
from conftest import assert_learned_the_maze, run_sharded

from jaxnav.config import TrainConfig
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
