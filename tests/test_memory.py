"""The recurrent network (``--memory``): a GRU cell whose hidden state is reset where an episode
starts, carried by the training loop and evaluation, learned over whole sequences by PQN.
(Kill -9 then ``--resume`` of a run with memory is in test_reliability.py; export in
test_export.py.)"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_TRAIN, assert_learned_the_maze

from jaxnav.agents import dqn
from jaxnav.config import TrainConfig
from jaxnav.evaluate import evaluate_seeds, run_episodes
from jaxnav.train import Trainer
from jaxnav.train.__main__ import main as train_main

# TINY_TRAIN as PQN with a GRU of 8 units: 4 envs x 4 steps per rollout, episodes of at most 3
# steps (so every rollout crosses episode boundaries), 2 minibatches of 2 envs' sequences
TINY_MEMORY = dataclasses.replace(
    TINY_TRAIN,
    env_kwargs={"size": 5, "max_steps": 3},
    algo="pqn",
    layer_norm=True,
    rollout_length=4,
    num_epochs=2,
    num_minibatches=2,
    memory=8,
)


@pytest.fixture(scope="module")
def network() -> tuple[dqn.QNetwork, dict]:
    net = dqn.QNetwork(num_actions=4, hidden_sizes=(16,), layer_norm=True, memory=8)
    return net, net.init(jax.random.key(0), jnp.zeros((1, 6)))


def test_an_episodes_q_values_do_not_depend_on_the_previous_episode(network):
    net, params = network
    k_a, k_b, k_ep, k_h = jax.random.split(jax.random.key(1), 4)
    envs, size = 2, 6
    previous_a = jax.random.normal(k_a, (3, envs, size))  # two different previous episodes,
    previous_b = jax.random.normal(k_b, (3, envs, size))  # started from different states
    hidden_a, hidden_b = jax.random.normal(k_h, (2, envs, 8))
    episode = jax.random.normal(k_ep, (5, envs, size))
    done = jnp.zeros((8, envs), bool).at[2].set(True)  # the previous episodes' last step

    def q(previous, hidden, done):
        sequence = jnp.concatenate([previous, episode])
        return np.asarray(dqn.unroll(net.apply, params, sequence, hidden, done)[0])

    q_a, q_b = q(previous_a, hidden_a, done), q(previous_b, hidden_b, done)
    np.testing.assert_array_equal(q_a[3:], q_b[3:])
    assert not np.allclose(q_a[:3], q_b[:3])
    # the same as the episode played from an episode's start
    alone = dqn.unroll(net.apply, params, episode, net.initial_memory(envs), done[3:])[0]
    np.testing.assert_allclose(q_a[3:], alone, rtol=1e-6, atol=1e-6)
    # without the reset the previous episode would show
    never = jnp.zeros_like(done)
    assert not np.allclose(q(previous_a, hidden_a, never)[3:], q(previous_b, hidden_b, never)[3:])


def test_q_values_depend_on_the_episodes_earlier_observations(network):
    net, params = network
    obs = jax.random.normal(jax.random.key(2), (4, 2, 6))
    other = obs.at[0].set(-obs[0])  # only the first observation differs
    done = jnp.zeros((4, 2), bool)
    q = dqn.unroll(net.apply, params, obs, net.initial_memory(2), done)[0]
    q_other = dqn.unroll(net.apply, params, other, net.initial_memory(2), done)[0]
    for t in range(1, 4):
        assert not np.allclose(q[t], q_other[t])


@pytest.fixture(scope="module")
def memory_trainer() -> Trainer:
    return Trainer(TINY_MEMORY)


def test_the_loop_resets_the_state_where_an_episode_ends_as_learning_does(memory_trainer):
    """The acting passes' hidden states are zero after an episode's last step, and the
    sequence learning recomputes (from the rollout's first state, resets at ``done``) gives
    the Q-values the rollout acted on."""
    trainer = memory_trainer
    ts = trainer.init(jax.random.key(0))
    assert ts.memory.shape == (4, 8) and not ts.memory.any()

    @jax.jit
    def rollout(ts, key):
        def step(ts, k):
            return trainer.env_step(ts, tuple(jax.random.split(k, 3)), 0.5, ts.params)

        return jax.lax.scan(step, ts, jax.random.split(key, 12))

    end, (tr, finite, _) = jax.device_get(rollout(ts, jax.random.key(1)))
    assert finite.all() and tr.done.any() and not tr.done.all()
    after = np.concatenate([tr.memory[1:], end.memory[None]])
    assert not after[tr.done].any()  # zeros where an episode starts
    assert np.abs(after[~tr.done]).min(axis=-1).all()  # a state elsewhere
    q = dqn.unroll(trainer.network.apply, ts.params, tr.obs, tr.memory[0], tr.done)[0]
    np.testing.assert_allclose(q.max(axis=-1), tr.value, rtol=1e-6, atol=1e-6)


@pytest.fixture(scope="module")
def memory_run(memory_trainer):
    keys = jax.random.split(jax.random.key(0), 2)
    train = jax.jit(jax.vmap(memory_trainer.train))
    return jax.device_get(train(keys)), jax.device_get(train(keys))


def test_a_pqn_run_with_memory_trains_its_gru_and_repeats_bitwise(memory_run, memory_trainer):
    (state, metrics), (again, _) = memory_run
    assert not state.diverged.any() and np.isfinite(metrics["loss"]).all()
    assert (metrics["loss"] > 0).all()
    assert state.memory.shape == (2, 4, 8)
    init = jax.device_get(jax.vmap(memory_trainer.init)(jax.random.split(jax.random.key(0), 2)))
    for name, layer in state.params["params"]["memory"].items():
        before = init.params["params"]["memory"][name]
        assert not np.array_equal(layer["kernel"], before["kernel"]), name
    for leaf, leaf_again in zip(jax.tree.leaves(state), jax.tree.leaves(again), strict=True):
        if jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf, leaf_again = jax.random.key_data(leaf), jax.random.key_data(leaf_again)
        np.testing.assert_array_equal(leaf, leaf_again)


def test_greedy_evaluation_carries_the_state_through_each_episode(memory_run, memory_trainer):
    trainer = memory_trainer
    params = jax.tree.map(lambda x: x[0], memory_run[0][0].params)
    policy = trainer.greedy_policy(params)
    assert isinstance(policy, dqn.RecurrentPolicy)
    env, env_params = trainer.env, trainer.env_params
    key = jax.random.key(5)
    episodes = jax.device_get(run_episodes(env, env_params, policy, key, 6, 3))
    # the same episodes stepped here, the state carried by hand
    k_reset, k_run = jax.random.split(key)
    obs, state = jax.vmap(env.reset_layout, in_axes=(0, None, 0))(
        jax.random.split(k_reset, 6), env_params, jnp.zeros(6, jnp.int32)
    )
    hidden, ended, ret = trainer.network.initial_memory(6), np.zeros(6, bool), np.zeros(6)
    for k in jax.random.split(k_run, 3):
        q, hidden = trainer.network.apply(params, obs, hidden)
        action = jnp.argmax(q, axis=-1)
        obs, state, reward, terminated, truncated, _ = jax.vmap(
            env.step_no_reset, in_axes=(0, 0, 0, None)
        )(jax.random.split(jax.random.split(k)[1], 6), state, action, env_params)
        ret += np.where(ended, 0.0, reward)
        ended |= np.asarray(terminated | truncated)
    np.testing.assert_allclose(episodes["return"], ret, rtol=1e-6)
    rows = evaluate_seeds(trainer, memory_run[0][0].params, 8, seed=0)
    assert len(rows) == 2 and all(0.0 <= r["success_rate"] <= 1.0 for r in rows)


@pytest.mark.parametrize(
    "overrides, named",
    [
        (dict(algo="dqn", memory=8), "memory=8: algo=dqn"),
        (dict(algo="pqn", memory=-1), "memory=-1"),
        (dict(algo="pqn", num_envs=4, rollout_length=2, num_minibatches=8, memory=8),
         "num_minibatches=8 does not divide num_envs=4"),
    ],
)  # fmt: skip
def test_bad_memory_settings_are_refused_naming_the_value(overrides, named):
    with pytest.raises(ValueError, match=named) as error:
        dataclasses.replace(TINY_TRAIN, **overrides).validate()
    assert "\n" not in str(error.value)


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["pqn", "ppo"])
def test_a_recurrent_network_learns_a_small_maze(algo):
    """The bar of test_pqn.py's and test_ppo.py's feed-forward networks, with a GRU of 32
    units: a 7x7 maze, greedy success >= 0.9 on near-shortest paths."""
    config = TrainConfig.for_env(
        "GridMaze-v0",
        algo=algo,
        env_kwargs={"size": 7, "max_steps": 30},
        hidden_sizes=(64, 64),
        total_timesteps=65_536,
        eps_decay_steps=32_000,
        log_interval=16_384,
        memory=32,
    )
    trainer = Trainer(config)
    key = jax.random.split(jax.random.key(0), 3)[0]
    state, metrics = jax.jit(trainer.train)(key)
    assert_learned_the_maze(trainer, state.params, metrics, 0.9)


def test_cli_refuses_memory_for_the_dqn_in_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    assert train_main(["--algo", "dqn", "--memory", "8", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "memory=8" in err and "pqn, ppo" in err
    assert not out.exists()
