"""PQN (``--algo pqn``): lambda-return targets against a plain reference, learning the grid,
seeds, the bfloat16 option, no replay memory, and its configurations refused with a reason.
(Kill -9 then ``--resume`` is in test_reliability.py, parametrized over the algorithms.)"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_TRAIN, assert_learned_the_maze
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxnav.agents import dqn, pqn
from jaxnav.config import TrainConfig
from jaxnav.train import Trainer, Transitions, jit_training
from jaxnav.train.__main__ import main as train_main

# TINY_TRAIN as PQN: 4 envs x 2 steps per rollout, 2 minibatches of 4 transitions, 2 epochs
TINY_PQN = dataclasses.replace(
    TINY_TRAIN,
    algo="pqn",
    layer_norm=True,
    rollout_length=2,
    num_epochs=2,
    num_minibatches=2,
)


# ------------------------------------------------------------------ lambda-returns
def reference_lambda_returns(reward, terminated, done, next_value, gamma, lam):
    """The recursion of ``pqn.lambda_returns``'s docstring, one env and one step at a time."""
    reward, next_value = np.asarray(reward, np.float64), np.asarray(next_value, np.float64)
    steps, envs = reward.shape
    g = np.zeros((steps, envs))
    for n in range(envs):
        for t in reversed(range(steps)):
            if t == steps - 1 or done[t, n]:
                boot = next_value[t, n]
            else:
                boot = (1 - lam) * next_value[t, n] + lam * g[t + 1, n]
            g[t, n] = reward[t, n] + gamma * (1 - terminated[t, n]) * boot
    return g


lambda_returns = jax.jit(pqn.lambda_returns, static_argnames="unrolled")


def returns_of(reward, terminated, done, next_value, gamma, lam, unrolled=False) -> np.ndarray:
    return np.asarray(
        lambda_returns(
            jnp.asarray(reward, jnp.float32),
            jnp.asarray(terminated, bool),
            jnp.asarray(done, bool),
            jnp.asarray(next_value, jnp.float32),
            jnp.float32(gamma),
            jnp.float32(lam),
            unrolled=unrolled,
        )
    )


# one rollout of 4 steps in 4 envs, laid out [time, env]:
# env 0 runs on, env 1 is truncated (time limit) after step 1, env 2 terminates (goal) after
# step 1, env 3 terminates on the rollout's last step
REWARD = np.array(
    [[0.0, 0.1, -0.2, 0.0], [0.5, 1.0, 1.0, 0.3], [0.0, -0.5, 0.2, 0.0], [1.0, 0.0, 0.0, 1.0]]
)
NEXT_VALUE = np.array(
    [[2.0, 0.4, 0.3, -1.0], [3.0, 5.0, 7.0, 0.5], [-1.0, 0.6, 0.9, 2.0], [4.0, 0.8, 0.1, 9.0]]
)
DONE = np.zeros((4, 4), bool)
TERMINATED = np.zeros((4, 4), bool)
DONE[1, 1] = DONE[1, 2] = DONE[3, 3] = True
TERMINATED[1, 2] = TERMINATED[3, 3] = True
GAMMA = 0.9


@pytest.mark.parametrize("unrolled", [False, True])  # the loop (CPU) or straight-line (GPU)
@pytest.mark.parametrize("lam", [0.0, 0.3, 0.65, 1.0])
def test_lambda_returns_match_the_reference_recursion(lam, unrolled):
    got = returns_of(REWARD, TERMINATED, DONE, NEXT_VALUE, GAMMA, lam, unrolled)
    want = reference_lambda_returns(REWARD, TERMINATED, DONE, NEXT_VALUE, GAMMA, lam)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


def test_lambda_returns_by_hand_at_episode_ends():
    lam, g, r, v = 0.5, GAMMA, REWARD, NEXT_VALUE
    got = returns_of(REWARD, TERMINATED, DONE, NEXT_VALUE, g, lam)
    # truncated after step 1: bootstraps from the final observation's value, not from step 2
    np.testing.assert_allclose(got[1, 1], r[1, 1] + g * v[1, 1], rtol=1e-6)
    np.testing.assert_allclose(
        got[0, 1], r[0, 1] + g * ((1 - lam) * v[0, 1] + lam * got[1, 1]), rtol=1e-6
    )
    # terminated after step 1: no bootstrap at all
    np.testing.assert_allclose(got[1, 2], r[1, 2], rtol=1e-6)
    np.testing.assert_allclose(
        got[0, 2], r[0, 2] + g * ((1 - lam) * v[0, 2] + lam * r[1, 2]), rtol=1e-6
    )
    # the next episode starts afresh: step 2 sees only its own future
    np.testing.assert_allclose(got[3, 2], r[3, 2] + g * v[3, 2], rtol=1e-6)
    # terminated on the rollout's last step
    np.testing.assert_allclose(got[3, 3], r[3, 3], rtol=1e-6)
    # the rollout's last step of a running episode bootstraps fully
    np.testing.assert_allclose(got[3, 0], r[3, 0] + g * v[3, 0], rtol=1e-6)


def test_lambda_0_is_one_step_targets():
    got = returns_of(REWARD, TERMINATED, DONE, NEXT_VALUE, GAMMA, 0.0)
    np.testing.assert_allclose(got, REWARD + GAMMA * (1 - TERMINATED) * NEXT_VALUE, rtol=1e-6)


def test_lambda_1_is_monte_carlo_within_the_rollout_then_bootstrap():
    got = returns_of(REWARD, TERMINATED, DONE, NEXT_VALUE, GAMMA, 1.0)
    r, v, g = REWARD, NEXT_VALUE, GAMMA
    # env 0 never ends: discounted rewards to the rollout's end, then its last next value
    for t in range(4):
        want = sum(g ** (k - t) * r[k, 0] for k in range(t, 4)) + g ** (4 - t) * v[3, 0]
        np.testing.assert_allclose(got[t, 0], want, rtol=1e-6)
    # env 2 terminates after step 1: a plain Monte-Carlo return, no value at all
    np.testing.assert_allclose(got[0, 2], r[0, 2] + g * r[1, 2], rtol=1e-6)
    # env 1 is truncated after step 1: Monte-Carlo to the cut, then the final observation
    np.testing.assert_allclose(got[0, 1], r[0, 1] + g * r[1, 1] + g**2 * v[1, 1], rtol=1e-6)


@settings(max_examples=25, deadline=None)
@given(
    steps=st.integers(1, 6),
    envs=st.integers(1, 3),
    gamma=st.floats(0.0, 1.0),
    lam=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**31 - 1),
)
@pytest.mark.parametrize("unrolled", [False, True])
def test_lambda_returns_match_the_reference_on_random_rollouts(
    steps, envs, gamma, lam, seed, unrolled
):
    rng = np.random.default_rng(seed)
    reward = rng.normal(size=(steps, envs))
    next_value = rng.normal(scale=3.0, size=(steps, envs))
    done = rng.random((steps, envs)) < 0.3
    terminated = done & (rng.random((steps, envs)) < 0.5)  # a terminal state ends the episode
    got = returns_of(reward, terminated, done, next_value, gamma, lam, unrolled)
    want = reference_lambda_returns(reward, terminated, done, next_value, gamma, lam)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


# ------------------------------------------------------------------ bootstrap values
NEXT_STEPS, NEXT_ENVS = 6, 4


@pytest.fixture(scope="module")
def next_values_of(pqn_trainer):
    """``(done, terminated) -> (next_values, one forward pass over next_obs, the acting
    pass's values of the following steps)`` on a hand-made rollout of NEXT_STEPS x NEXT_ENVS:
    observations from env resets; after a step that ends an episode, next_obs is another
    (final) observation than the next step's."""
    trainer = pqn_trainer
    steps, envs = NEXT_STEPS, NEXT_ENVS
    q_max = lambda params, obs: trainer.network.apply(params, obs).max(axis=-1)  # noqa: E731

    @jax.jit
    def run(params, done, terminated):
        keys = jax.random.split(jax.random.key(7), (2 * steps + 1) * envs)
        pool, _ = jax.vmap(trainer.env.reset, in_axes=(0, None))(keys, trainer.env_params)
        obs = pool[: steps * envs].reshape(steps, envs, -1)
        last_obs = pool[steps * envs : (steps + 1) * envs]
        final = pool[(steps + 1) * envs :].reshape(steps, envs, -1)
        following = jnp.concatenate([obs[1:], last_obs[None]])
        next_obs = jnp.where(done[..., None], final, following)
        zeros = jnp.zeros((steps, envs))
        tr = Transitions(
            obs, zeros.astype(jnp.int32), zeros, next_obs, terminated, done, q_max(params, obs)
        )
        acted = q_max(params, following)
        values = trainer.algorithm.next_values(params, tr, last_obs)
        return values, q_max(params, next_obs), acted

    params = jax.jit(trainer.init)(jax.random.key(0)).params
    return lambda done, terminated: run(params, jnp.asarray(done), jnp.asarray(terminated))


@settings(max_examples=25, deadline=None)
@given(
    cut_step=st.lists(st.integers(-1, NEXT_STEPS - 1), min_size=NEXT_ENVS, max_size=NEXT_ENVS),
    ends=st.lists(st.booleans(), min_size=NEXT_STEPS * NEXT_ENVS, max_size=NEXT_STEPS * NEXT_ENVS),
    cut_every_step=st.booleans(),
)
def test_next_values_are_one_pass_over_next_observations(
    next_values_of, pqn_trainer, cut_step, ends, cut_every_step
):
    """PQN's bootstrap values, taken from the acting passes and a pass over the final
    observations of time-limit cuts, equal one forward pass over every next observation
    wherever a target bootstraps: each env cut at most once (one row an env) or,
    ``cut_every_step``, env 0 cut every step (more than a time limit allows)."""
    assert pqn_trainer.env_params.max_steps_in_episode >= NEXT_STEPS  # one cut an env fits
    done = np.array(ends).reshape(NEXT_STEPS, NEXT_ENVS)
    terminated = done.copy()
    for env, step in enumerate(cut_step):
        if step >= 0:
            done[step, env], terminated[step, env] = True, False
    if cut_every_step:
        done[:, 0], terminated[:, 0] = True, False
    values, one_pass, _ = jax.device_get(next_values_of(done, terminated))
    boots = ~terminated
    np.testing.assert_allclose(values[boots], one_pass[boots], rtol=1e-5, atol=1e-5)


def test_next_values_read_final_observations_where_the_time_limit_cut(next_values_of):
    """At a cut step the value is the final observation's, not the next step's (the reset's):
    the case a bootstrap from the acting pass alone would get wrong."""
    done = np.zeros((NEXT_STEPS, NEXT_ENVS), bool)
    done[2, 1] = done[0, 3] = True
    values, one_pass, acted = jax.device_get(next_values_of(done, np.zeros_like(done)))
    np.testing.assert_allclose(values, one_pass, rtol=1e-5, atol=1e-5)
    assert not np.allclose(one_pass[done], acted[done])  # the two differ at the cuts
    np.testing.assert_allclose(values[~done], acted[~done], rtol=1e-5, atol=1e-5)  # acting pass


# ------------------------------------------------------------------ minibatch order
@settings(max_examples=15, deadline=None)
@given(n=st.sampled_from([1, 2, 3, 8, 1000, 1024, 4096, 4097]), seed=st.integers(0, 2**31 - 1))
def test_shuffled_rows_visit_every_row_once(n, seed):
    """Each epoch's order is a permutation, for powers of two (the sort-free bijection) and
    other row counts (``jax.random.permutation``) alike. Few row counts: each one compiles."""
    order = np.asarray(pqn.shuffled_rows(jax.random.key(seed), n))
    assert order.dtype == np.int32
    np.testing.assert_array_equal(np.sort(order), np.arange(n))


def test_shuffled_rows_mix_time_steps_and_envs_into_every_minibatch():
    """A rollout of 32 steps of 8,192 envs (rows ``t * 8192 + env``, RobotNav-v0's preset) cut
    into 16 minibatches: each minibatch holds every time step about equally often, as a
    random permutation's would (chi-square per degree of freedom near 1, not the
    hundreds of a contiguous or strided cut), adjacent positions are uncorrelated, and two
    keys give different orders."""
    steps, envs, minibatches = 32, 8192, 16
    order = np.asarray(pqn.shuffled_rows(jax.random.key(1), steps * envs))
    per_step = np.stack(
        [np.bincount(mb // envs, minlength=steps) for mb in order.reshape(minibatches, -1)]
    )
    expected = steps * envs / minibatches / steps
    chi2_per_dof = ((per_step - expected) ** 2 / expected).sum(axis=1).mean() / (steps - 1)
    assert 0.5 < chi2_per_dof < 1.6, chi2_per_dof
    assert abs(np.corrcoef(order[:-1], order[1:])[0, 1]) < 0.01
    other = np.asarray(pqn.shuffled_rows(jax.random.key(2), steps * envs))
    assert (order == other).mean() < 0.01


# ------------------------------------------------------------------ tiny runs
@pytest.fixture(scope="module")
def pqn_trainer() -> Trainer:
    return Trainer(TINY_PQN)


@pytest.fixture(scope="module")
def pqn_train(pqn_trainer):
    """``jit(vmap(trainer.train))`` over keys."""
    return jax.jit(jax.vmap(pqn_trainer.train))


def test_pqn_allocates_no_replay_memory_and_no_target_network(pqn_trainer):
    state = jax.eval_shape(pqn_trainer.init, jax.random.key(0))
    assert state.algo_state is None  # nothing of its own beside the shared state
    assert pqn_trainer.config.first_learning_iteration == 0  # learns from its first rollout


def test_seeds_give_different_parameters_and_a_seed_repeats_bitwise(pqn_train, pqn_trainer):
    keys = jax.random.split(jax.random.key(0), 2)
    state, metrics = jax.device_get(pqn_train(keys))
    again, _ = jax.device_get(pqn_train(keys))
    for leaf, leaf_again in zip(
        jax.tree.leaves(state.params), jax.tree.leaves(again.params), strict=True
    ):
        np.testing.assert_array_equal(leaf, leaf_again)
        assert not np.array_equal(leaf[0], leaf[1])
    assert not state.diverged.any() and np.isfinite(metrics["loss"]).all()
    # every iteration learned: the loss is logged from the first interval on
    assert (metrics["loss"] > 0).all()
    assert metrics["env_steps"][0].tolist() == [32, 64, 96]


def test_training_options_compile_here_and_compute_what_plain_jit_does(pqn_train, pqn_trainer):
    # ``jit_training`` is how the CLI compiles training: its XLA options must be valid for the
    # installed jaxlib (an unknown value fails the compile) and change scheduling, not values
    keys = jax.random.split(jax.random.key(3), 2)
    plain = jax.device_get(pqn_train(keys))
    tuned = jax.device_get(jit_training(jax.vmap(pqn_trainer.train))(keys))
    for leaf, leaf_tuned in zip(jax.tree.leaves(plain), jax.tree.leaves(tuned), strict=True):
        if jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf, leaf_tuned = jax.random.key_data(leaf), jax.random.key_data(leaf_tuned)
        np.testing.assert_array_equal(leaf, leaf_tuned)


def test_memory_check_counts_the_rollout_not_a_replay_buffer():
    """A buffer size the DQN's replay could not hold is no obstacle to PQN, which keeps one
    rollout; a rollout too large is refused naming the sizes PQN uses."""
    big = dataclasses.replace(
        TINY_TRAIN, num_seeds=64, num_envs=2**16, buffer_size=10**9, learning_starts=2**16
    )
    big = dataclasses.replace(big, total_timesteps=2**18, log_interval=2**16)
    with pytest.raises(ValueError, match=r"buffer_size=1000000000.*GiB"):
        Trainer(big)
    Trainer(dataclasses.replace(big, algo="pqn"))  # 64 seeds x 2**16 envs x 1 step: fits
    huge = dataclasses.replace(big, algo="pqn", num_envs=2**20, rollout_length=64)
    huge = dataclasses.replace(huge, total_timesteps=2**26, log_interval=2**26)
    with pytest.raises(ValueError, match=r"rollout_length=64.*num_envs=1048576.*GiB") as info:
        Trainer(huge)
    assert "buffer_size" not in str(info.value)


# ------------------------------------------------------------------ bfloat16
@pytest.mark.parametrize("layer_norm", [False, True], ids=["plain", "layer-norm"])
def test_bfloat16_network_is_float32_network_within_bf16_rounding(layer_norm):
    kw = dict(num_actions=4, hidden_sizes=(64, 64), layer_norm=layer_norm)
    net32 = dqn.QNetwork(**kw)
    net16 = dqn.QNetwork(**kw, compute_dtype="bfloat16")
    obs = jax.random.normal(jax.random.key(0), (64, 10))
    params = jax.jit(net32.init)(jax.random.key(1), obs)
    # the same parameters (float32 in both) fit both networks
    like16 = jax.eval_shape(net16.init, jax.random.key(1), obs)
    assert jax.tree.map(lambda x: (x.shape, x.dtype), params) == jax.tree.map(
        lambda x: (x.shape, x.dtype), like16
    )
    q32 = np.asarray(jax.jit(net32.apply)(params, obs))
    q16 = jax.jit(net16.apply)(params, obs)
    assert q16.dtype == jnp.float32
    q16 = np.asarray(q16)
    scale = np.abs(q32).max()
    np.testing.assert_allclose(q16, q32, rtol=2e-2, atol=2e-2 * scale)
    assert not np.array_equal(q16, q32)  # the products did run in bfloat16


@pytest.mark.parametrize("norm_impl", ["flax", "fused"])
@pytest.mark.parametrize("dueling", [False, True])
def test_acting_weights_cast_once_give_the_same_q_values(norm_impl, dueling):
    """A rollout acts with ``compute_params``: the hidden weights cast to bfloat16 once, the
    heads and LayerNorm parameters left in float32, the Q-values bit for bit the same."""
    net = dqn.QNetwork(
        4, (64, 32), dueling=dueling, layer_norm=True, compute_dtype="bfloat16",
        norm_impl=norm_impl,
    )  # fmt: skip
    obs = jax.random.normal(jax.random.key(0), (33, 10))
    params = jax.jit(net.init)(jax.random.key(1), obs)
    cast = net.compute_params(params)
    dtypes = {"/".join(k.key for k in path): x.dtype for path, x in jax.tree.leaves_with_path(cast)}
    assert {k for k, d in dtypes.items() if d == jnp.bfloat16} == {
        "params/Dense_0/kernel",
        "params/Dense_1/kernel",
    }
    apply = jax.jit(net.apply)
    np.testing.assert_array_equal(apply(cast, obs), apply(params, obs))


def test_bfloat16_pqn_run_trains_without_divergence():
    trainer = Trainer(dataclasses.replace(TINY_PQN, compute_dtype="bfloat16"))
    state, metrics = jax.device_get(jax.jit(trainer.train)(jax.random.key(0)))
    assert int(state.diverged) == 0
    assert np.isfinite(metrics["loss"]).all() and np.isfinite(metrics["q_mean"]).all()
    assert all(x.dtype == jnp.float32 for x in jax.tree.leaves(state.params))


# ------------------------------------------------------------------ refused configurations
@pytest.mark.parametrize(
    "overrides, named",
    [
        (dict(algo="pqn", num_envs=4, rollout_length=2, num_minibatches=3), "num_minibatches=3"),
        (dict(algo="dqn", rollout_length=2), "rollout_length=2"),
        (dict(algo="sac"), "algo='sac'"),
        (dict(algo="pqn", compute_dtype="float16"), "compute_dtype='float16'"),
    ],
)
def test_bad_pqn_settings_are_refused_naming_the_value(overrides, named):
    with pytest.raises(ValueError, match=named):
        dataclasses.replace(TINY_TRAIN, **overrides).validate()


def test_cli_refuses_an_unknown_algorithm_in_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    assert train_main(["--algo", "sac", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "sac" in err and "Traceback" not in err
    assert "dqn" in err and "pqn" in err  # says what would do
    assert not out.exists()


# ------------------------------------------------------------------ learning
@pytest.mark.slow
@pytest.mark.parametrize("fused", [False, True], ids=["flax-norm", "fused-norm"])
def test_pqn_learns_a_small_maze(fused):
    """The bar of test_learning.py's DQN: a 7x7 maze, greedy success >= 0.95 (0.99-1.0 over
    seeds 0-4, 0.2 s of training each on one CPU core), also with the fused LayerNorm."""
    config = TrainConfig.for_env(
        "GridMaze-v0",
        algo="pqn",
        env_kwargs={"size": 7, "max_steps": 30},
        hidden_sizes=(64, 64),
        total_timesteps=65_536,
        eps_decay_steps=32_000,
        log_interval=16_384,
        fused_layer_norm=fused,
    )
    trainer = Trainer(config)
    state, metrics = jax.jit(trainer.train)(jax.random.key(0))
    assert_learned_the_maze(trainer, state.params, metrics, 0.95)
