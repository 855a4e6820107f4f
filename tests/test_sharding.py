"""Training sharded over devices (``--devices``): the tests run with 2 CPU devices (conftest)."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from conftest import TINY_TRAIN, run_sharded

from jaxnav import sharding
from jaxnav.config import TrainConfig
from jaxnav.sharding import ENVS, SEEDS
from jaxnav.train import Trainer
from jaxnav.train.__main__ import main as train_main

# two logging intervals of random actions only, then learning
WARM_UP = dataclasses.replace(TINY_TRAIN, learning_starts=64)
KEY = jax.random.split(jax.random.key(3), 1)


def test_session_has_two_devices():
    assert jax.device_count() == 2


@pytest.mark.parametrize(
    ("num_seeds", "devices", "shape"),
    [(1, 1, (1, 1)), (1, 2, (1, 2)), (2, 2, (2, 1)), (3, 2, (1, 2))],
)
def test_devices_go_to_seeds_first(num_seeds, devices, shape):
    assert sharding.mesh_shape(num_seeds, devices) == shape


def test_env_shards_step_their_envs_exactly_as_one_device():
    one = Trainer(WARM_UP)
    two = Trainer(dataclasses.replace(WARM_UP, devices=2))
    state1, metrics1 = run_sharded(one, KEY, num_logs=2)
    state2, metrics2 = run_sharded(two, KEY, num_logs=2)
    # really split: each device holds half of each seed's envs and replay columns
    assert {s.data.shape for s in state2.obs.addressable_shards} == {(1, 2, one.obs_size)}
    rows = WARM_UP.buffer_rows
    assert {s.data.shape for s in state2.algo_state.buffer.obs.addressable_shards} == {
        (1, rows, 2, one.obs_size)
    }
    # the same global random numbers, so the same episodes and replay contents, bit for bit
    for name in ("obs", "env_state", "episode_return", "episode_length"):
        a, b = jax.device_get(getattr(state1, name)), jax.device_get(getattr(state2, name))
        jax.tree.map(np.testing.assert_array_equal, a, b)
    a, b = jax.device_get((state1.algo_state.buffer, state2.algo_state.buffer))
    jax.tree.map(np.testing.assert_array_equal, a, b)
    for k in metrics1:
        np.testing.assert_array_equal(metrics1[k], metrics2[k], err_msg=k)


def test_env_shards_train_one_agent_as_one_device():
    """Updates included: each device computes the gradient of its half of the batch and XLA
    sums them, so the run matches one device up to the order of floating-point sums."""
    trainer = Trainer(dataclasses.replace(TINY_TRAIN, devices=2))
    state, metrics = run_sharded(trainer, KEY)
    assert metrics["loss"][0, -1] > 0  # it learned
    # parameters and optimizer state are replicated over the env blocks: each device's own
    # copy, not one device's copy reported twice, must be the same after the updates
    for tree in (state.params, state.opt_state, state.algo_state.target_params):
        for leaf in jax.tree.leaves(tree):
            copies = [np.asarray(s.data) for s in leaf.addressable_shards]
            assert len(copies) == 2
            np.testing.assert_array_equal(copies[0], copies[1])
    one_state, one_metrics = run_sharded(Trainer(TINY_TRAIN), KEY)
    for k in metrics:
        np.testing.assert_allclose(metrics[k], one_metrics[k], rtol=1e-5, atol=1e-6, err_msg=k)
    close = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)  # noqa: E731
    jax.tree.map(close, jax.device_get(one_state.params), jax.device_get(state.params))


def test_seed_shards_train_each_seed_as_one_device():
    keys = jax.random.split(jax.random.key(5), 2)
    config = dataclasses.replace(TINY_TRAIN, num_seeds=2)
    state1, metrics1 = run_sharded(Trainer(config), keys)
    two = Trainer(dataclasses.replace(config, devices=2))
    assert two.mesh.shape == {SEEDS: 2, ENVS: 1}
    state2, metrics2 = run_sharded(two, keys)
    kernel = state2.params["params"]["value"]["kernel"]
    assert {s.data.shape[0] for s in kernel.addressable_shards} == {1}  # a seed per device
    for k in metrics1:
        np.testing.assert_allclose(metrics1[k], metrics2[k], rtol=1e-5, atol=1e-6, err_msg=k)
    assert not np.array_equal(metrics1["loss"][0], metrics1["loss"][1])  # two seeds differ


def test_bad_device_counts_are_refused_before_work(tmp_path, capsys):
    flags = ["--total-timesteps", "64", "--num-envs", "3", "--out", str(tmp_path / "run")]
    assert train_main([*flags, "--devices", "all"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(
        "num_envs=3 is not a multiple of the 2 devices each seed's envs are "
        "split over (devices=2, num_seeds=1)"
    ), err
    assert train_main([*flags[:-2], "--out", str(tmp_path / "run"), "--devices", "3"]) == 2
    assert "devices=3: only 2 device(s) are available" in capsys.readouterr().err
    assert train_main([*flags, "--devices", "two"]) == 2
    assert "invalid device count 'two'" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_cli_devices_all_records_the_count(tmp_path):
    from conftest import TINY_FLAGS

    out = tmp_path / "run"
    code = train_main([*TINY_FLAGS, "--total-timesteps", "64", "--eval-episodes", "4",
                       "--devices", "all", "--out", str(out)])  # fmt: skip
    assert code == 0
    from jaxnav import run_dir

    assert run_dir.load_config(out).devices == 2


def test_config_names_the_indivisible_batch():
    with pytest.raises(ValueError, match="batch_size=7 is not a multiple of the 2 devices"):
        TrainConfig(num_envs=4, batch_size=7, devices=2).validate()


# PQN with the fused LayerNorm at a width the kernels take (128) and rows they fit on each of
# two devices (32 envs a device acting, 64 rows a device in a minibatch)
FUSED_PQN = dataclasses.replace(
    TINY_TRAIN, algo="pqn", layer_norm=True, fused_layer_norm=True, hidden_sizes=(128,),
    num_envs=64, rollout_length=4, num_minibatches=2, num_epochs=1, total_timesteps=512,
    log_interval=256,
)  # fmt: skip


@pytest.mark.parametrize("num_seeds", [1, 2], ids=["env-shards", "seed-shards"])
def test_kernels_over_devices_train_as_one_device(num_seeds, monkeypatch):
    """The LayerNorm kernels (Pallas's interpreter here, as on a GPU) on each device's rows
    or seeds train what one device trains, up to the order of floating-point sums."""
    monkeypatch.setattr(Trainer, "norm_impl", staticmethod(lambda config: "pallas"))
    keys = jax.random.split(jax.random.key(7), num_seeds)
    config = dataclasses.replace(FUSED_PQN, num_seeds=num_seeds)
    two = Trainer(dataclasses.replace(config, devices=2))
    assert two.learner_network.norm_impl == "pallas" and two.learner_network.mesh.size == 2
    assert two.network.mesh is None  # evaluation and export: one device's arrays
    _, interval, state_like = two.sharded(keys)
    program = str(jax.make_jaxpr(interval)(state_like, np.int32(0)))
    assert "pallas_call" in program and "shard_map" in program  # the kernels, on each device
    state2, metrics2 = run_sharded(two, keys)
    state1, metrics1 = run_sharded(Trainer(config), keys)
    assert metrics1["loss"].shape == (num_seeds, 2) and (metrics1["loss"] > 0).all()
    for k in metrics1:
        np.testing.assert_allclose(metrics1[k], metrics2[k], rtol=1e-4, atol=1e-5, err_msg=k)
    close = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)  # noqa: E731
    jax.tree.map(close, jax.device_get(state1.params), jax.device_get(state2.params))


@pytest.mark.parametrize("algo", ["pqn", "ppo"])
def test_a_recurrent_network_over_devices_trains_as_one_device(algo):
    """``--memory``: each device steps half of a seed's envs and holds their hidden states;
    a minibatch's sequences are split over the devices as one device's rows would be. (No
    dueling heads: a policy's logits leave V without a gradient but rounding, which Adam
    scales up.)"""
    config = dataclasses.replace(
        TINY_TRAIN, algo=algo, layer_norm=True, rollout_length=4, num_minibatches=2,
        num_epochs=2, memory=8, total_timesteps=128, dueling=False,
    )  # fmt: skip
    two = Trainer(dataclasses.replace(config, devices=2))
    state2, metrics2 = run_sharded(two, KEY)
    assert {s.data.shape for s in state2.memory.addressable_shards} == {(1, 2, 8)}
    state1, metrics1 = run_sharded(Trainer(config), KEY)
    assert (metrics1["loss"] != 0).all()
    for k in metrics1:
        np.testing.assert_allclose(metrics1[k], metrics2[k], rtol=1e-5, atol=1e-6, err_msg=k)
    close = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)  # noqa: E731
    jax.tree.map(close, jax.device_get(state1.params), jax.device_get(state2.params))
    jax.tree.map(close, jax.device_get(state1.memory), jax.device_get(state2.memory))


def test_config_names_a_minibatch_of_sequences_the_devices_cannot_split():
    config = dataclasses.replace(
        TINY_TRAIN, algo="pqn", num_envs=4, rollout_length=2, num_minibatches=4, memory=8,
        devices=2,
    )  # fmt: skip
    with pytest.raises(ValueError, match="num_minibatches=4: with memory=8 a minibatch's 1 envs"):
        config.validate()
