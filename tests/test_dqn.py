"""DQN pieces (network heads, TD targets, replay buffer) and the Trainer's run-level behaviour."""

from __future__ import annotations

import dataclasses
from functools import partial

import chex
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from conftest import TINY_TRAIN  # pytest puts tests/ on sys.path
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxnav import train
from jaxnav.agents import dqn
from jaxnav.algos.base import ProgramLayout
from jaxnav.train import Trainer

NUM_ACTIONS = 4


def leaves_equal(a, b) -> bool:
    return all(
        np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )


def assert_trees_allclose(a, b, **kw):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), **kw)


def stack(*trees):
    return jax.tree.map(lambda *x: jnp.stack(x), *trees)


# compiled once for the module (eager dispatch of these costs seconds per test)
td_loss = jax.jit(dqn.td_loss, static_argnames=("apply_fn", "double", "loss_type"))
buffer_sample = jax.jit(dqn.buffer_sample, static_argnames=("batch_size", "n_step"))
buffer_add = jax.jit(dqn.buffer_add)


# ------------------------------------------------------------------------------ network
def test_dueling_head_is_value_plus_centred_advantage():
    net = dqn.QNetwork(NUM_ACTIONS, hidden_sizes=(8, 8), dueling=True)
    obs = jax.random.normal(jax.random.key(0), (5, 3))
    params = jax.jit(net.init)(jax.random.key(1), obs)
    p = params["params"]
    assert {"value", "advantage"} <= set(p)
    apply = jax.jit(partial(net.apply, capture_intermediates=True, mutable=["intermediates"]))
    q, captured = apply(params, obs)
    chex.assert_shape(q, (5, NUM_ACTIONS))
    # the heads read the last hidden layer's ReLU; V and A as two separate products
    features = np.maximum(np.asarray(captured["intermediates"]["Dense_1"]["__call__"][0]), 0.0)
    v = features @ np.asarray(p["value"]["kernel"]) + np.asarray(p["value"]["bias"])
    a = features @ np.asarray(p["advantage"]["kernel"]) + np.asarray(p["advantage"]["bias"])
    chex.assert_shape(v, (5, 1))
    np.testing.assert_allclose(q, v + a - a.mean(-1, keepdims=True), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(q.mean(-1), v[:, 0], rtol=1e-5, atol=1e-6)


def test_dueling_head_with_hand_set_parameters():
    net = dqn.QNetwork(NUM_ACTIONS, hidden_sizes=(4,), dueling=True)
    params = jax.jit(net.init)(jax.random.key(0), jnp.zeros((1, 2)))
    p = params["params"]
    p = {
        **p,
        "value": {"kernel": jnp.zeros_like(p["value"]["kernel"]), "bias": jnp.array([5.0])},
        "advantage": {
            "kernel": jnp.zeros_like(p["advantage"]["kernel"]),
            "bias": jnp.array([1.0, 2.0, 3.0, 6.0]),
        },
    }
    q = jax.jit(net.apply)({"params": p}, jax.random.normal(jax.random.key(1), (3, 2)))
    # V + A - mean(A) = 5 + [1, 2, 3, 6] - 3
    np.testing.assert_allclose(q, np.tile([3.0, 4.0, 5.0, 8.0], (3, 1)), atol=1e-6)


def test_onehot_sizes_expand_index_observations_to_the_onehot_network():
    """A network with ``onehot_sizes`` on compact codes is the same function, with the same
    parameters, as the plain network on their one-hot encoding."""
    sizes = (3, 0, 5, 0)
    codes = jnp.array([[2, -4, 0, 1], [0, 7, 4, 0]], jnp.int8)
    onehot = jnp.array([[0, 0, 1, -4, 1, 0, 0, 0, 0, 1], [1, 0, 0, 7, 0, 0, 0, 0, 1, 0]], jnp.int8)
    np.testing.assert_array_equal(dqn.expand_onehot(codes, sizes), onehot)
    assert dqn.input_size(4, sizes) == 10 and dqn.input_size(4, None) == 4
    compact = dqn.QNetwork(NUM_ACTIONS, hidden_sizes=(8,), onehot_sizes=sizes)
    plain = dqn.QNetwork(NUM_ACTIONS, hidden_sizes=(8,))
    params = jax.jit(compact.init)(jax.random.key(0), jnp.zeros((1, 4)))
    chex.assert_shape(params["params"]["Dense_0"]["kernel"], (10, 8))
    np.testing.assert_array_equal(
        jax.jit(compact.apply)(params, codes), jax.jit(plain.apply)(params, onehot)
    )


def test_plain_network_has_no_value_head():
    net = dqn.QNetwork(NUM_ACTIONS, hidden_sizes=(8,), dueling=False)
    params = jax.jit(net.init)(jax.random.key(0), jnp.zeros((1, 3)))
    names = set(params["params"])
    assert "value" not in names and "advantage" not in names
    assert len(names) == 2  # one hidden layer, one output layer
    chex.assert_shape(jax.jit(net.apply)(params, jnp.zeros((7, 3))), (7, NUM_ACTIONS))


# ---------------------------------------------------------------------------- TD targets
# A lookup "network": params 0 is the online net, 1 the target net; obs[:, 0] is a state id.
Q_TABLES = jnp.array(
    [
        [[0.0, 0.0, 0.0, 0.0], [1.0, 5.0, 2.0, 0.0], [7.0, 1.0, 0.0, 0.0]],  # online
        [[0.0, 0.0, 0.0, 0.0], [3.0, 0.5, 4.0, 1.0], [1.5, 2.0, 0.0, 9.0]],  # target
    ]
)
ONLINE, TARGET = jnp.int32(0), jnp.int32(1)
Q_TAKEN = 20.0  # Q(s, a) of the sampled pairs, above every target


def lookup_apply(which, obs):
    q = Q_TABLES[which][obs[:, 0].astype(jnp.int32)]
    return q.at[:, 0].set(jnp.where(obs[:, 0] == 0, Q_TAKEN, q[:, 0]))  # state 0, action 0


def td_target(batch: dqn.Batch, double: bool) -> np.ndarray:
    """Per-sample TD target recovered from td_loss (mse, Q(s, a) = Q_TAKEN)."""
    targets = []
    for i in range(batch.obs.shape[0]):
        one = jax.tree.map(lambda x, i=i: x[i : i + 1], batch)
        loss, _ = td_loss(ONLINE, TARGET, lookup_apply, one, double, "mse")
        targets.append(Q_TAKEN - float(np.sqrt(loss)))
    return np.array(targets)


def make_batch(next_states, returns, discounts) -> dqn.Batch:
    n = len(next_states)
    return dqn.Batch(
        obs=jnp.zeros((n, 1)),
        action=jnp.zeros(n, jnp.int32),
        returns=jnp.asarray(returns, jnp.float32),
        bootstrap_obs=jnp.asarray(next_states, jnp.float32)[:, None],
        bootstrap_discount=jnp.asarray(discounts, jnp.float32),
    )


def test_double_and_simple_targets_match_hand_computation():
    batch = make_batch(next_states=[1, 2], returns=[1.0, 0.5], discounts=[0.9, 0.81])
    # simple DQN (eq. 5): r + d * max_a Q_target(s', a)
    np.testing.assert_allclose(td_target(batch, False), [1 + 0.9 * 4, 0.5 + 0.81 * 9], rtol=1e-5)
    # double DQN (eq. 6): r + d * Q_target(s', argmax_a Q_online(s', a))
    # s'=1: online argmax 1 -> target 0.5; s'=2: online argmax 0 -> target 1.5
    np.testing.assert_allclose(td_target(batch, True), [1 + 0.9 * 0.5, 0.5 + 0.81 * 1.5], rtol=1e-5)


def test_td_loss_gradient_flows_only_through_online_q():
    net = dqn.QNetwork(NUM_ACTIONS, hidden_sizes=(8,), dueling=True)
    obs = jax.random.normal(jax.random.key(0), (6, 3))
    init = jax.jit(net.init)
    params, target_params = init(jax.random.key(1), obs), init(jax.random.key(2), obs)
    batch = dqn.Batch(obs, jnp.arange(6) % 4, jnp.ones(6), obs[::-1], jnp.full(6, 0.9))
    loss = lambda p, tp, double: dqn.td_loss(p, tp, net.apply, batch, double)[0]  # noqa: E731
    grad = jax.jit(jax.grad(loss, argnums=(0, 1)), static_argnums=2)
    for double in (False, True):
        g, g_target = grad(params, target_params, double)
        assert all(float(jnp.abs(x).max()) == 0.0 for x in jax.tree.leaves(g_target))
        chex.assert_tree_all_finite(g)
        assert any(float(jnp.abs(x).max()) > 0.0 for x in jax.tree.leaves(g))


@pytest.mark.parametrize("loss_type", ["huber", "mse"])
def test_regression_loss_and_its_gradient_match_numpy(loss_type):
    """The loss reads only each sample's taken action; its gradient is the loss's derivative
    there over the batch size, zero at every other action; diagnostics as logged."""
    rng = np.random.default_rng(0)
    q = rng.normal(0.0, 2.0, (256, NUM_ACTIONS)).astype(np.float32)
    action = rng.integers(0, NUM_ACTIONS, 256)
    target = rng.normal(0.0, 2.0, 256).astype(np.float32)
    identity = lambda params, obs: params  # noqa: E731  the "network" returns its Q-values

    def loss(q):
        return dqn.regression_loss(q, identity, None, jnp.asarray(action), target, loss_type)

    (value, aux), grad = jax.jit(jax.value_and_grad(loss, has_aux=True))(jnp.asarray(q))
    td = q[np.arange(256), action].astype(np.float64) - target
    if loss_type == "huber":
        want, slope = np.where(np.abs(td) <= 1, 0.5 * td**2, np.abs(td) - 0.5), np.clip(td, -1, 1)
    else:
        want, slope = td**2, 2 * td
    want_grad = np.zeros(q.shape)
    want_grad[np.arange(256), action] = slope / 256
    np.testing.assert_allclose(value, want.mean(), rtol=1e-5)
    np.testing.assert_allclose(grad, want_grad, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(aux["loss"], want, rtol=1e-5)
    np.testing.assert_allclose(aux["q_mean"], q[np.arange(256), action], rtol=1e-6)
    np.testing.assert_array_equal(aux["q_max"], np.abs(q).max(axis=-1))


def test_diagnostics_summed_over_steps_are_the_means_of_each_steps_means():
    """Per-row sums over a loop's steps reduce to the mean of each step's mean loss and
    Q-value, and the largest |Q| of any step; a NaN in any step shows in the result."""
    rng = np.random.default_rng(1)
    steps = [
        {name: rng.normal(size=8).astype(np.float32) for name in dqn.DIAGNOSTICS} for _ in range(2)
    ]
    for step in steps:
        step["q_max"] = np.abs(step["q_max"])

    def means_of(steps):
        total = dqn.diagnostics_init(8)
        for step in steps:
            total = dqn.diagnostics_add(total, step)
        return dqn.diagnostics_means(total, len(steps))

    means = means_of(steps)
    for name in ("loss", "q_mean"):
        np.testing.assert_allclose(means[name], np.mean([s[name].mean() for s in steps]), 1e-6)
    assert float(means["q_max"]) == max(s["q_max"].max() for s in steps)
    steps[1]["q_max"][3] = np.nan
    assert np.isnan(means_of(steps)["q_max"])


def test_taken_values_masked_and_gathered_agree_with_their_gradients():
    """The GPU's masked sum and the CPU's take_along_axis: the same values and gradients."""
    q = jax.random.normal(jax.random.key(0), (64, NUM_ACTIONS))
    action = jax.random.randint(jax.random.key(1), (64,), 0, NUM_ACTIONS)
    weight = jax.random.normal(jax.random.key(2), (64,))
    for masked in (False, True):
        grad = jax.grad(lambda q, m=masked: (dqn.taken_values(q, action, m) * weight).sum())(q)
        np.testing.assert_array_equal(
            dqn.taken_values(q, action, masked), q[jnp.arange(64), action]
        )
        want = jnp.zeros_like(q).at[jnp.arange(64), action].set(weight)
        np.testing.assert_array_equal(grad, want)


def test_terminated_does_not_bootstrap_truncated_does():
    """One row, env 0 terminated, env 1 truncated (done, not terminated), both reward 1."""
    gamma = 0.9
    buf = dqn.buffer_init(4, 2, 1)
    buf = buffer_add(
        buf,
        obs=jnp.zeros((2, 1)),
        action=jnp.zeros(2, jnp.int32),
        reward=jnp.ones(2),
        next_obs=jnp.array([[1.0], [1.0]]),  # the final observation (state 1)
        terminated=jnp.array([True, False]),
        done=jnp.array([True, True]),
    )
    batch = buffer_sample(buf, jax.random.key(0), 16, 1, jnp.float32(gamma))
    envs = np.asarray(batch.bootstrap_discount > 0).astype(int)  # 1 for the truncated env
    assert set(envs.tolist()) == {0, 1}
    np.testing.assert_allclose(batch.bootstrap_discount, gamma * envs)
    np.testing.assert_array_equal(batch.bootstrap_obs[:, 0], 1.0)
    for double in (False, True):
        expected = np.where(envs == 1, 1.0 + gamma * (0.5 if double else 4.0), 1.0)
        np.testing.assert_allclose(td_target(batch, double), expected, rtol=1e-5)


# ------------------------------------------------------------------------- replay buffer
def filled_buffer(capacity, num_envs, rows, terminated=None, done=None):
    """Row t holds obs (t, env), next_obs (t + 0.5, env), reward 1 + t + 10 env, action t % 4."""
    buf = dqn.buffer_init(capacity, num_envs, 2)
    env = jnp.arange(num_envs, dtype=jnp.float32)
    for t in range(rows):
        buf = buffer_add(
            buf,
            jnp.stack([jnp.full(num_envs, t, jnp.float32), env], -1),
            jnp.full(num_envs, t % 4, jnp.int32),
            1.0 + t + 10.0 * env,
            jnp.stack([jnp.full(num_envs, t + 0.5, jnp.float32), env], -1),
            jnp.zeros(num_envs, bool) if terminated is None else jnp.asarray(terminated[t]),
            jnp.zeros(num_envs, bool) if done is None else jnp.asarray(done[t]),
        )
    return buf


def test_buffer_wraps_around_keeping_newest_rows():
    buf = filled_buffer(4, 2, 3)
    assert int(buf.ptr) == 3 and int(buf.size) == 3 and buf.capacity == 4
    buf = filled_buffer(4, 2, 6)
    assert int(buf.ptr) == 2 and int(buf.size) == 4
    # rows 0 and 1 were overwritten by times 4 and 5
    np.testing.assert_array_equal(buf.obs[:, 0, 0], [4, 5, 2, 3])
    np.testing.assert_array_equal(buf.obs[:, 1, 1], 1)
    np.testing.assert_array_equal(buf.reward[:, 1], [15, 16, 13, 14])
    np.testing.assert_array_equal(buf.action[:, 0], [0, 1, 2, 3])
    np.testing.assert_array_equal(buf.next_obs[:, 0, 0], [4.5, 5.5, 2.5, 3.5])


# 7 rows into 5 slots: times 2..6 remain. env 0 terminates at t=3; env 1 is truncated at t=4
# and terminates at t=6.
T, E, CAP = 7, 2, 5
TERM = np.zeros((T, E), bool)
DONE = np.zeros((T, E), bool)
TERM[3, 0] = DONE[3, 0] = True
DONE[4, 1] = True
TERM[6, 1] = DONE[6, 1] = True


def reference_nstep(t, e, n, gamma):
    """Plain-Python n-step return, bootstrap discount and bootstrap time."""
    g = 0.0
    for k in range(n):
        g += gamma**k * (1 + (t + k) + 10 * e)
        if DONE[t + k, e]:
            return g, 0.0 if TERM[t + k, e] else gamma ** (k + 1), t + k
    return g, gamma**n, t + n - 1


@pytest.fixture(scope="module")
def episode_buffer():
    return filled_buffer(CAP, E, T, TERM, DONE)


@pytest.mark.parametrize("n_step", [1, 2, 3])
def test_nstep_sampling_matches_reference(episode_buffer, n_step):
    gamma = 0.5
    batch = buffer_sample(episode_buffer, jax.random.key(n_step), 1024, n_step, gamma)
    t = np.asarray(batch.obs[:, 0]).astype(int)
    e = np.asarray(batch.obs[:, 1]).astype(int)
    # every start whose n rows are all in the buffer, and no other (the write pointer is
    # between times 6 and 2: a window may not run past the newest row)
    valid = {(ti, ei) for ti in range(2, T - n_step + 1) for ei in range(E)}
    assert set(zip(t.tolist(), e.tolist(), strict=True)) == valid
    np.testing.assert_array_equal(batch.action, t % 4)
    ref = [reference_nstep(ti, ei, n_step, gamma) for ti, ei in zip(t, e, strict=True)]
    returns, discount, boot_t = (np.array(x) for x in zip(*ref, strict=True))
    np.testing.assert_allclose(batch.returns, returns, rtol=1e-6)
    np.testing.assert_allclose(batch.bootstrap_discount, discount, rtol=1e-6)
    np.testing.assert_array_equal(batch.bootstrap_obs[:, 0], boot_t + 0.5)
    np.testing.assert_array_equal(batch.bootstrap_obs[:, 1], e)


def test_one_step_sample_is_reward_and_gamma_times_not_terminated(episode_buffer):
    gamma = 0.9
    batch = buffer_sample(episode_buffer, jax.random.key(5), 512, 1, jnp.float32(gamma))
    t = np.asarray(batch.obs[:, 0]).astype(int)
    e = np.asarray(batch.obs[:, 1]).astype(int)
    np.testing.assert_allclose(batch.returns, 1 + t + 10 * e)
    np.testing.assert_allclose(batch.bootstrap_discount, gamma * (1 - TERM[t, e]), rtol=1e-6)
    np.testing.assert_array_equal(batch.bootstrap_obs[:, 0], t + 0.5)


@settings(max_examples=20, deadline=None)
@given(rows=st.integers(3, 20), n_step=st.integers(1, 3), seed=st.integers(0, 2**31 - 1))
def test_sampling_never_crosses_write_pointer(rows, n_step, seed):
    """Without episode ends, every sampled window is n consecutive times, all still stored."""
    cap = 6
    buf = filled_buffer(cap, 1, rows)
    batch = buffer_sample(buf, jax.random.key(seed), 256, n_step, 1.0)
    t = np.asarray(batch.obs[:, 0]).astype(int)
    oldest = max(0, rows - cap)
    assert t.min() >= oldest and t.max() <= rows - n_step
    np.testing.assert_array_equal(batch.bootstrap_obs[:, 0], t + n_step - 0.5)
    expected = sum(1 + t + k for k in range(n_step))  # gamma = 1: plain sums
    np.testing.assert_allclose(batch.returns, expected)


# ---------------------------------------------------------------------- probe learning
def test_q_learning_probe_recovers_known_values():
    """Two states: s0 -> terminal with reward 1 (Q = 1), s1 -> s0 with reward 0 (Q = gamma),
    for every action. Train the dueling net with double-DQN targets on exactly these."""
    gamma = 0.9
    net = dqn.QNetwork(NUM_ACTIONS, hidden_sizes=(32,), dueling=True)
    s0, s1 = jnp.array([1.0, 0.0]), jnp.array([0.0, 1.0])
    actions = jnp.arange(NUM_ACTIONS)
    obs = jnp.concatenate([jnp.tile(s0, (4, 1)), jnp.tile(s1, (4, 1))])
    batch = dqn.Batch(
        obs=obs,
        action=jnp.concatenate([actions, actions]),
        returns=jnp.concatenate([jnp.ones(4), jnp.zeros(4)]),
        bootstrap_obs=jnp.tile(s0, (8, 1)),
        bootstrap_discount=jnp.concatenate([jnp.zeros(4), jnp.full(4, gamma)]),
    )
    params = jax.jit(net.init)(jax.random.key(0), obs)
    opt = optax.adam(3e-3)

    def step(carry, i):
        params, target, opt_state = carry
        grads = jax.grad(lambda p: dqn.td_loss(p, target, net.apply, batch, True)[0])(params)
        updates, opt_state = opt.update(grads, opt_state)
        params = optax.apply_updates(params, updates)
        target = jax.tree.map(
            lambda t, p: jnp.where(i % 50 == 49, p, t), target, params
        )  # hard copy every 50 steps
        return (params, target, opt_state), None

    (params, _, _), _ = jax.jit(lambda c: jax.lax.scan(step, c, jnp.arange(500)))(
        (params, params, opt.init(params))
    )
    q = jax.jit(net.apply)(params, jnp.stack([s0, s1]))
    np.testing.assert_allclose(q[0], 1.0, atol=0.05)
    np.testing.assert_allclose(q[1], gamma, atol=0.05)


# ------------------------------------------------------------------------------ trainer
def test_target_updates_exactly_when_env_steps_cross_the_period(stepwise_trainer, stepwise_run_one):
    trainer, run_one = stepwise_trainer, stepwise_run_one
    c = trainer.config
    assert c.iterations_per_log == 1 and c.target_update_period % c.num_envs != 0
    ts = jax.jit(trainer.init)(jax.random.key(0))
    period = c.target_update_period
    updated_at = []
    for it in range(c.iterations):
        before, online_before = ts.algo_state.target_params, ts.params
        ts, metrics = run_one(ts, it)
        target = ts.algo_state.target_params
        assert int(metrics["env_steps"][0]) == (it + 1) * c.num_envs
        learning = it * c.num_envs >= c.learning_starts
        if learning:
            assert not leaves_equal(ts.params, online_before)  # a gradient step happened
        else:
            assert leaves_equal(ts.params, online_before)
        if leaves_equal(target, ts.params) and not leaves_equal(target, before):
            updated_at.append(it)
        else:
            assert leaves_equal(target, before)  # otherwise untouched
    # iteration it takes env steps from it*N to (it+1)*N: a copy when a multiple of the
    # period lies in (it*N, (it+1)*N], once learning has started
    expected = [
        it
        for it in range(c.iterations)
        if it * c.num_envs >= c.learning_starts
        and (it + 1) * c.num_envs // period > it * c.num_envs // period
    ]
    assert expected == [2, 4, 7, 9, 12, 14]  # N=4, period 10, learning from step 8
    assert updated_at == expected


def iteration_by_iteration(config):
    """``(it, state before, state after)`` of each iteration of ``config``, run one iteration
    per call of ``Trainer.run`` as ``stepwise_trainer`` does (its log_interval: num_envs)."""
    trainer = Trainer(dataclasses.replace(config, log_interval=config.num_envs))
    run_one = jax.jit(lambda ts, it: trainer.run(ts, it, 1))
    ts = jax.jit(trainer.init)(jax.random.key(0))
    for it in range(trainer.config.iterations):
        before = ts
        ts, _ = run_one(ts, it)
        yield it, before, ts


@pytest.mark.parametrize("select", [False, True], ids=["cond", "select"])
def test_target_updates_at_the_gradient_step_whose_env_steps_cross_the_period(
    tiny_config, monkeypatch, select
):
    """4 envs and 4 gradient steps an iteration: each step stands for one env step. With a
    period of 3, iteration i crosses multiples of 3 in (4i, 4i + 4]; the hard copy after the
    iteration is the parameters after the last step that crossed one, so it equals the final
    parameters exactly when 4i + 4 is a multiple of 3, and otherwise those of an earlier step
    (neither the iteration's final parameters nor the previous target). Both forms of the
    update: the CPU's cond and the GPU's select."""
    monkeypatch.setattr(
        train, "program_layout", lambda *_: ProgramLayout(target_update_select=select)
    )
    c = dataclasses.replace(
        tiny_config, batch_size=2, replay_ratio=2.0, target_update_period=3,
        total_timesteps=10 * tiny_config.num_envs,
    )  # fmt: skip
    assert c.updates_per_iteration == 4 and c.num_envs == 4 and c.learning_start_steps == 8
    for it, before, ts in iteration_by_iteration(c):
        target, target_before = ts.algo_state.target_params, before.algo_state.target_params
        if it < 2:  # no learning yet
            assert leaves_equal(target, target_before)
            continue
        assert not leaves_equal(target, target_before)
        assert leaves_equal(target, ts.params) == ((4 * it + 4) % 3 == 0), it


@pytest.mark.parametrize(
    ("num_envs", "n_step", "first"), [(4, 1, 2), (3, 1, 3), (16, 1, 1), (16, 3, 3), (16384, 1, 1)]
)
def test_learning_starts_rounds_up_to_whole_iterations_and_n_step_rows(num_envs, n_step, first):
    """learning_starts=8 waits whole iterations of num_envs steps, and at least n_step of them
    (replay must hold an n-step transition), so one default holds at any env count."""
    c = dataclasses.replace(
        TINY_TRAIN, num_envs=num_envs, n_step=n_step, batch_size=num_envs * 2,
        buffer_size=num_envs * 16, total_timesteps=num_envs * 8, log_interval=num_envs,
    )  # fmt: skip
    c.validate()
    assert c.first_learning_iteration == first
    assert c.learning_start_steps == first * num_envs >= max(c.learning_starts, num_envs * n_step)


def test_updates_wait_for_n_step_rows_when_learning_starts_is_below_them(tiny_config):
    """learning_starts=1 with 3-step returns: the first gradient step is in iteration 3."""
    c = dataclasses.replace(
        tiny_config, n_step=3, learning_starts=1, total_timesteps=5 * tiny_config.num_envs
    )
    changed = [
        not leaves_equal(ts.params, before.params) for _, before, ts in iteration_by_iteration(c)
    ]
    assert changed == [False, False, False, True, True]


# The compiled runs are the expensive part: each is used by as few tests as possible, since
# pytest-xdist spreads adjacent tests over workers and each worker compiles its own.
def seed1_run(train_one):
    return train_one(jax.random.key(1))


def test_same_seed_is_bitwise_reproducible_and_seeds_differ(train_one, seed0_run):
    ts0, metrics0 = seed0_run
    ts, metrics = train_one(jax.random.key(0))
    assert leaves_equal(ts.params, ts0.params)
    assert leaves_equal(ts.algo_state.target_params, ts0.algo_state.target_params)
    assert leaves_equal(metrics, metrics0)
    chex.assert_tree_all_finite((ts0.params, metrics0))
    assert int(metrics0["episodes"].sum()) > 0  # the metrics describe real episodes
    assert float(metrics0["loss"][-1]) > 0  # and real gradient steps
    ts1, metrics1 = seed1_run(train_one)
    assert not leaves_equal(ts0.params, ts1.params)
    assert not leaves_equal(metrics0["mean_return"], metrics1["mean_return"])


def test_index_observation_trains_exactly_as_onehot(tiny_config, seed0_run):
    """GridMaze's default ``index`` observation, one-hot encoded by the network, gives the
    same run as the ``onehot`` observation, bit for bit, with a 10-value replay."""
    assert tiny_config.env_kwargs.get("obs_mode", "index") == "index"
    kwargs = {**tiny_config.env_kwargs, "obs_mode": "onehot"}
    onehot = Trainer(dataclasses.replace(tiny_config, env_kwargs=kwargs))
    ts, metrics = jax.jit(onehot.train)(jax.random.key(0))
    index_obs, onehot_obs = seed0_run[0].algo_state.buffer.obs, ts.algo_state.buffer.obs
    chex.assert_shape(index_obs, (*onehot_obs.shape[:2], 10))
    assert onehot_obs.shape[-1] == 4 * 5 + 4 + 2
    assert leaves_equal(ts.params, seed0_run[0].params)
    assert leaves_equal(metrics, seed0_run[1])


def test_vmap_over_seeds_and_hparams(tiny_trainer, train_one, train_many, seed0_run):
    """jit(vmap(train)) over two seeds equals the two runs done separately; over two learning
    rates (HParams leaves) it runs both and they differ."""
    hp = tiny_trainer.default_hparams()
    k0, k1 = jax.random.key(0), jax.random.key(1)
    ts_b, metrics_b = train_many(stack(k0, k1), stack(hp, hp))
    for i, (ts, metrics) in enumerate([seed0_run, seed1_run(train_one)]):
        pick = lambda x, i=i: x[i]  # noqa: E731
        assert_trees_allclose(jax.tree.map(pick, ts_b.params), ts.params, rtol=1e-4, atol=1e-5)
        assert_trees_allclose(jax.tree.map(pick, metrics_b), metrics, rtol=1e-4, atol=1e-5)

    hps = stack(hp, hp.replace(lr=jnp.float32(1e-2)))
    chex.assert_shape(hps.lr, (2,))
    ts_lr, metrics_lr = train_many(stack(k0, k0), hps)
    chex.assert_tree_all_finite(ts_lr.params)
    np.testing.assert_allclose(ts_lr.hparams.lr, [hp.lr, 1e-2])
    first, second = (jax.tree.map(lambda x, i=i: x[i], ts_lr.params) for i in range(2))
    assert_trees_allclose(first, seed0_run[0].params, rtol=1e-4, atol=1e-5)
    assert not leaves_equal(first, second)
    assert float(metrics_lr["lr"][0, 0]) != float(metrics_lr["lr"][1, 0])


@pytest.mark.parametrize("updates", [3, 4])
def test_updates_unrolled_two_a_trip_train_exactly_as_rolled(monkeypatch, updates):
    """On a GPU the DQN's gradient steps run two a loop trip (``ProgramLayout.updates_unroll``),
    also where their count is odd; on a CPU one. The same run either way: the same samples,
    target updates and episodes, and parameters equal up to float rounding (XLA may fuse the
    unrolled body's arithmetic otherwise)."""
    config = dataclasses.replace(
        TINY_TRAIN, batch_size=8, replay_ratio=2.0 * updates, total_timesteps=64, n_step=2
    )
    assert config.updates_per_iteration == updates
    runs = []
    for unroll in (1, 2):
        layout = ProgramLayout(updates_unroll=unroll)
        monkeypatch.setattr(train, "program_layout", lambda *_, layout=layout: layout)
        runs.append(jax.jit(Trainer(config).train)(jax.random.key(5)))
    rolled, unrolled = (jax.tree.leaves(run) for run in runs)
    for a, b in zip(rolled, unrolled, strict=True):
        if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        if jnp.issubdtype(a.dtype, jnp.floating):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
        else:
            np.testing.assert_array_equal(a, b)  # counts, actions, episodes, keys
    assert float(runs[1][1]["loss"][-1]) > 0.0


def test_polyak_is_optax_incremental_update_and_tau_one_copies():
    """The target network's update (``optax.incremental_update``) computes the hand-written
    ``tau * params + (1 - tau) * target`` bit for bit; tau 1 is a hard copy."""
    from jaxnav.agents.dqn import polyak

    key_a, key_b = jax.random.split(jax.random.key(3))
    params = {"w": jax.random.normal(key_a, (7, 5)), "b": jnp.arange(5.0)}
    target = {"w": jax.random.normal(key_b, (7, 5)), "b": -jnp.arange(5.0)}
    for tau in (1.0, 0.5, 0.005):
        tau = jnp.float32(tau)
        hand = jax.tree.map(lambda t, p, k=tau: k * p + (1.0 - k) * t, target, params)
        chex.assert_trees_all_equal(polyak(target, params, tau), hand)
    chex.assert_trees_all_equal(polyak(target, params, jnp.float32(1.0)), params)
