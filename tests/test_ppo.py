"""PPO (``--algo ppo``): GAE and the clipped loss against references computed by hand, actions
sampled from the policy, learning the grid, and a CLI run that evaluates and exports."""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_TRAIN, assert_learned_the_maze

from jaxnav import export
from jaxnav.algos import ppo
from jaxnav.config import TrainConfig
from jaxnav.deploy.policy import Policy
from jaxnav.evaluate.__main__ import main as evaluate_main
from jaxnav.train import Trainer
from jaxnav.train.__main__ import main as train_main


def reference_gae(reward, terminated, done, value, next_value, gamma, lam):
    """GAE one env and one step at a time, from the last step back: a terminated step does
    not bootstrap, a truncated one bootstraps from its final observation's value, and no
    step carries the next episode's advantage."""
    steps, envs = reward.shape
    advantage = np.zeros((steps, envs))
    for n in range(envs):
        following = 0.0
        for t in reversed(range(steps)):
            bootstrap = 0.0 if terminated[t, n] else gamma * next_value[t, n]
            delta = reward[t, n] + bootstrap - value[t, n]
            following = delta + (0.0 if done[t, n] else gamma * lam * following)
            advantage[t, n] = following
    return advantage, advantage + value


gae = jax.jit(ppo.gae)


def test_gae_matches_the_reference_with_terminations_and_truncations():
    rng = np.random.default_rng(0)
    steps, envs = 12, 5
    reward = rng.normal(size=(steps, envs)).astype(np.float32)
    done = rng.random((steps, envs)) < 0.25
    terminated = done & (rng.random((steps, envs)) < 0.5)  # the rest cut by the time limit
    assert (done & ~terminated).any() and terminated.any()
    value, next_value = (rng.normal(size=(steps, envs)).astype(np.float32) for _ in range(2))
    got = gae(reward, terminated, done, value, next_value, 0.9, 0.8)
    want = reference_gae(reward, terminated, done, value, next_value, 0.9, 0.8)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(np.asarray(g), w, rtol=1e-5, atol=1e-5)


def test_gae_by_hand_at_a_truncation_and_a_termination():
    # one env: step 0 cut by the time limit (final obs worth 10), step 1 the next episode's
    # first, step 2 terminated; gamma 0.5, lambda 1, values 0 but the bootstraps
    reward = np.array([[1.0], [2.0], [3.0]], np.float32)
    done = np.array([[True], [False], [True]])
    terminated = np.array([[False], [False], [True]])
    value = np.zeros((3, 1), np.float32)
    next_value = np.array([[10.0], [0.0], [99.0]], np.float32)  # 99: never read
    advantage, returns = gae(reward, terminated, done, value, next_value, 0.5, 1.0)
    # step 2: 3; step 1: 2 + 0.5 * 3 = 3.5; step 0: 1 + 0.5 * 10 (and not the next episode's)
    np.testing.assert_allclose(np.asarray(advantage)[:, 0], [6.0, 3.5, 3.0])
    np.testing.assert_allclose(np.asarray(returns), np.asarray(advantage))


def test_clipped_loss_by_hand_on_two_rows():
    # both rows pi = (0.5, 0.5); row 0 took action 0 with old probability 0.25 (ratio 2,
    # advantage +1: clipped to 1.2), row 1 action 1 with old probability 1 (ratio 0.5,
    # advantage -1: clipped to 0.8, the lower surrogate -0.8 is taken); advantages [3, -1]
    # normalize to [1, -1]
    logits = jnp.zeros((2, 2))
    action = jnp.array([0, 1])
    old_log_prob = jnp.log(jnp.array([0.25, 1.0]))
    advantage = jnp.array([3.0, -1.0])
    # values: row 0 moved 0.5 from 0.5 to 1.0, its clipped value 0.7 is further from the
    # target 2 (1.69 > 1); row 1 unclipped (0 - (-1))^2 = 1
    value, old_value, target = jnp.array([1.0, 0.0]), jnp.array([0.5, 0.0]), jnp.array([2.0, -1.0])
    batch = (action, old_log_prob, advantage, old_value, target)

    surrogate = (1.2 - 0.8) / 2
    entropy = math.log(2.0)
    loss = ppo.ppo_loss(logits, value, batch, clip_eps=0.2, vf_coef=0.5, ent_coef=0.01)
    want = -surrogate - 0.01 * entropy + 0.5 * 0.5 * (1.69 + 1.0) / 2
    assert float(loss) == pytest.approx(want, rel=1e-6)
    unclipped = ppo.ppo_loss(logits, value, batch, 0.2, 0.5, 0.01, clip_value=False)
    assert float(unclipped) == pytest.approx(-surrogate - 0.01 * entropy + 0.25 * 1.0, rel=1e-6)

    # a clipped surrogate passes no gradient to the policy: both rows take theirs, so without
    # the entropy bonus the policy does not move; with ratios inside the range both rows do
    def actor(logits):
        return ppo.policy_loss(logits, action, old_log_prob, advantage, 0.2, 0.0)[0]

    grad = np.asarray(jax.grad(actor)(logits))
    np.testing.assert_array_equal(grad, np.zeros((2, 2)))
    inside = jnp.log(jnp.array([0.5, 0.5]))
    grad = np.asarray(
        jax.grad(lambda lg: ppo.policy_loss(lg, action, inside, advantage, 0.2, 0.0)[0])(logits)
    )
    assert (np.abs(grad) > 0).all()


def test_actions_are_sampled_from_the_policy_not_epsilon_greedy():
    trainer = Trainer(dataclasses.replace(TINY_TRAIN, algo="ppo", dueling=False))
    probs = np.array([0.6, 0.3, 0.1, 0.0])
    logits = jnp.log(jnp.tile(jnp.asarray(probs[: trainer.env.num_actions]), (20_000, 1)))
    keys = tuple(jax.random.split(jax.random.key(0)))
    actions = np.asarray(trainer.algorithm.choose_actions(logits, keys, jnp.zeros(())))
    freq = np.bincount(actions, minlength=len(logits[0])) / len(actions)
    np.testing.assert_allclose(freq, probs[: trainer.env.num_actions], atol=0.015)


def test_the_value_network_trains_beside_the_policy():
    config = dataclasses.replace(
        TINY_TRAIN, algo="ppo", rollout_length=8, num_minibatches=2, total_timesteps=128
    )
    trainer = Trainer(config)
    init = jax.jit(trainer.init)(jax.random.key(0))
    state, metrics = jax.device_get(jax.jit(trainer.train)(jax.random.key(0)))
    critic_before = jax.tree.leaves(jax.device_get(init.algo_state.critic_params))
    critic_after = jax.tree.leaves(state.algo_state.critic_params)
    assert all(not np.array_equal(a, b) for a, b in zip(critic_before, critic_after, strict=True))
    # the policy is the network evaluation and export read; the value has one output
    assert jax.tree.structure(state.params) == jax.tree.structure(jax.device_get(init.params))
    value = trainer.algorithm.critic.apply(state.algo_state.critic_params, np.asarray(state.obs))
    assert value.shape == (config.num_envs, 1)
    assert int(state.diverged) == 0 and np.isfinite(metrics["loss"]).all()


@pytest.mark.parametrize(
    "overrides, named",
    [
        (dict(num_envs=4, rollout_length=2, num_minibatches=3), "num_minibatches=3"),
        (dict(clip_eps=0.0), "clip_eps=0.0"),
        (dict(ent_coef=-0.1), "ent_coef=-0.1"),
        (dict(clip_value="yes"), "clip_value='yes'"),
    ],
)
def test_bad_ppo_settings_are_refused_naming_the_value(overrides, named):
    with pytest.raises(ValueError, match=named) as e:
        dataclasses.replace(TINY_TRAIN, algo="ppo", **overrides).validate()
    assert "\n" not in str(e.value)


def test_ppo_learns_a_small_maze():
    """A 7x7 maze in 32,768 env steps: the greedy policy (argmax of the logits) reaches the
    goal on near-shortest paths where the random agent rarely does."""
    config = TrainConfig.for_env(
        "GridMaze-v0",
        algo="ppo",
        env_kwargs={"size": 7, "max_steps": 30},
        hidden_sizes=(64, 64),
        total_timesteps=32_768,
        log_interval=8_192,
        eval_episodes=0,
    )
    trainer = Trainer(config)
    state, metrics = jax.jit(trainer.train)(jax.random.key(0))
    assert_learned_the_maze(trainer, state.params, metrics, 0.9)


PPO_FLAGS = [
    "--algo", "ppo",
    "--env-arg", "size=7",
    "--hidden-sizes", "32,32",
    "--num-envs", "8",
    "--rollout-length", "16",
    "--num-minibatches", "2",
    "--num-epochs", "2",
    "--total-timesteps", "2048",
    "--log-interval", "1024",
    "--eval-episodes", "20",
]  # fmt: skip


def test_algo_ppo_trains_from_the_cli_and_its_run_evaluates_and_exports(tmp_path, capsys):
    run = tmp_path / "run"
    assert train_main([*PPO_FLAGS, "--out", str(run)]) == 0
    assert "train success (sampled)" in capsys.readouterr().out  # not epsilon-greedy
    config = json.loads((run / "config.json").read_text())["config"]
    assert config["algo"] == "ppo" and config["clip_eps"] == 0.2 and config["dueling"] is False
    assert evaluate_main([str(run), "--episodes", "20"]) == 0
    result = json.loads((run / "eval.json").read_text())
    assert result["episodes"] == 20
    assert result["success_rate"] + result["collision_rate"] + result["timeout_rate"] == (
        pytest.approx(1.0)
    )
    # the exported policy acts as the trained one: the argmax of its logits
    assert export.main([str(run), "--out", str(run / "policy.npz")]) == 0
    trainer, params, _ = export.load_run(run)
    obs, _ = jax.vmap(trainer.env.reset, in_axes=(0, None))(
        jax.random.split(jax.random.key(5), 16), trainer.env_params
    )
    policy = Policy.load(run / "policy.npz")
    assert policy.metadata["network"]["output"].startswith("the policy's logits")
    want = np.asarray(trainer.greedy_policy(params)(None, obs))
    assert [policy.act(np.asarray(o)) for o in obs] == want.tolist()
