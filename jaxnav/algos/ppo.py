"""PPO (Schulman et al. 2017), as PureJaxRL writes it: every iteration is a rollout of
``rollout_length`` steps of every env, actions sampled from the policy's logits; advantages by
GAE(``gamma``, ``td_lambda``) from a value network; then ``num_epochs`` shuffled passes of
``num_minibatches`` gradient steps of the clipped surrogate (``clip_eps``) with an entropy bonus
(``ent_coef``), and of the (optionally clipped) value loss (``vf_coef``).

The policy is the trainer's network (``agents.dqn.QNetwork`` built from the network flags): its
outputs are the logits, so evaluation and export read the greedy action as their argmax, as for
a Q-network. The value network is the same MLP with one output, kept in ``algo_state`` with its
own optimizer state (PureJaxRL's actor-critic: two trunks); each network's gradient is clipped
to ``max_grad_norm`` on its own.

With ``memory`` the policy is recurrent (its GRU's state carried by the loop) and a minibatch
is the whole rollouts of some envs, the policy run over each from its state at the rollout's
start (``agents.dqn.unroll``); the value network stays feed-forward, a baseline of the
observation alone.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from jaxnav.agents import dqn, pqn
from jaxnav.algos.base import LossFn, RolloutAlgorithm, TrainState, Transitions

# added to the advantages' standard deviation before dividing by it (PureJaxRL's)
ADVANTAGE_EPS = 1e-8


@struct.dataclass
class PPOState:
    """What PPO adds to the training state: the value network and its optimizer state."""

    critic_params: Any
    critic_opt_state: Any


def gae(
    reward: jax.Array,
    terminated: jax.Array,
    done: jax.Array,
    value: jax.Array,
    next_value: jax.Array,
    gamma: jax.Array,
    lam: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """``(advantages, returns)`` of a rollout, [T, N] each: GAE(``gamma``, ``lam``) with
    ``delta_t = r_t + gamma (1 - terminated_t) next_value_t - value_t`` and ``A_t = delta_t +
    gamma lam (1 - done_t) A_{t+1}``, ``A_T = 0``. ``next_value`` is V of the observation after
    each step (the final one where the episode ended): a step cut by the time limit bootstraps
    from it, a terminated one does not, and neither carries the next episode's advantage."""

    def back(following: jax.Array, step: tuple) -> tuple[jax.Array, jax.Array]:
        r, term, d, v, nv = step
        delta = r + gamma * (1.0 - term) * nv - v
        advantage = delta + gamma * lam * (1.0 - d) * following
        return advantage, advantage

    steps = (reward, terminated.astype(jnp.float32), done.astype(jnp.float32), value, next_value)
    _, advantages = jax.lax.scan(back, jnp.zeros_like(reward[0]), steps, reverse=True)
    return advantages, advantages + value


def log_prob(logits: jax.Array, action: jax.Array) -> jax.Array:
    """log pi(action | logits) of a categorical policy, [B] (or the leading axes of both)."""
    log_pi = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(log_pi, action[..., None], axis=-1)[..., 0]


def policy_loss(
    logits: jax.Array,
    action: jax.Array,
    old_log_prob: jax.Array,
    advantage: jax.Array,
    clip_eps: float | jax.Array,
    ent_coef: float | jax.Array,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The clipped surrogate's loss minus ``ent_coef`` times the mean entropy, on a minibatch
    whose ``advantage`` is normalized here (mean 0, std 1); ``(loss, rows)`` with the per-row
    ``surrogate`` and ``entropy``."""
    adv = (advantage - advantage.mean()) / (advantage.std() + ADVANTAGE_EPS)
    ratio = jnp.exp(log_prob(logits, action) - old_log_prob)
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * adv)
    log_pi = jax.nn.log_softmax(logits, axis=-1)
    entropy = -(jnp.exp(log_pi) * log_pi).sum(axis=-1)
    loss = -surrogate.mean() - ent_coef * entropy.mean()
    return loss, {"surrogate": surrogate, "entropy": entropy}


def value_loss(
    value: jax.Array,
    old_value: jax.Array,
    target: jax.Array,
    clip_eps: float | jax.Array,
    clipped: bool,
) -> jax.Array:
    """Half the mean squared error of ``value`` against ``target``; with ``clipped`` the larger
    of it and that of ``value`` moved at most ``clip_eps`` from the rollout's ``old_value``."""
    losses = (value - target) ** 2
    if clipped:
        moved = old_value + jnp.clip(value - old_value, -clip_eps, clip_eps)
        losses = jnp.maximum(losses, (moved - target) ** 2)
    return 0.5 * losses.mean()


def ppo_loss(
    logits: jax.Array,
    value: jax.Array,
    batch: tuple[jax.Array, ...],
    clip_eps: float,
    vf_coef: float,
    ent_coef: float,
    clip_value: bool = True,
) -> jax.Array:
    """PureJaxRL's total loss of a minibatch ``batch = (action, old_log_prob, advantage,
    old_value, target)``: ``policy_loss + vf_coef * value_loss``. With two networks each one's
    gradient is that of its own term, which is how training takes them."""
    action, old_log_prob, advantage, old_value, target = batch
    actor, _ = policy_loss(logits, action, old_log_prob, advantage, clip_eps, ent_coef)
    return actor + vf_coef * value_loss(value, old_value, target, clip_eps, clip_value)


class PPO(RolloutAlgorithm):
    """A sampled policy and a value network over rollouts of many envs."""

    gpu_updates_unroll = 16
    outputs = "the policy's logits"
    acting = "sampled"
    summary = "a sampled policy and a value network over rollouts"

    def __init__(self, loop: Any):
        super().__init__(loop)
        # the value network: the policy's MLP (same flags) with one output, feed-forward
        self.critic = loop.network.clone(num_actions=1, dueling=False, memory=0)
        self.learner_critic = loop.learner_network.clone(num_actions=1, dueling=False, memory=0)

    def init_state(self, params: Any, key: jax.Array, hparams: Any) -> PPOState:
        critic = self.critic.init(key, jnp.zeros((1, self.loop.obs_size)))
        return PPOState(critic, self.loop.optimizer(hparams).init(critic))

    def choose_actions(
        self, outputs: jax.Array, keys: tuple[jax.Array, jax.Array], eps: jax.Array
    ) -> jax.Array:
        """Sampled from the policy's logits ``outputs`` (``eps`` is not read)."""
        return jax.random.categorical(keys[0], outputs, axis=-1)

    def minibatch_loss(self, ts: TrainState) -> LossFn:
        """The policy's loss (``policy_loss``) on ``(obs, action, old_log_prob, advantage)``;
        with memory on whole sequences of B envs (each of those [B, T, ...]) followed by
        ``done [B, T]`` and ``hidden [B, H]``, their state at the sequences' start."""
        c, apply = self.config, self.loop.learner_network.apply

        def loss_fn(params, batch):
            obs, action, old_log_prob, advantage, *memory = batch
            if memory:
                logits = dqn.sequence_outputs(apply, params, obs, memory[1], memory[0])
                action, old_log_prob, advantage = (
                    x.reshape(-1) for x in (action, old_log_prob, advantage)
                )
            else:
                logits = apply(params, obs)
            return policy_loss(logits, action, old_log_prob, advantage, c.clip_eps, c.ent_coef)

        return loss_fn

    def value_fn(self, critic_params: Any, obs: jax.Array) -> jax.Array:
        """V(obs) of the value network, the leading axes of ``obs`` kept."""
        flat = obs.reshape(-1, obs.shape[-1])
        return self.learner_critic.apply(critic_params, flat)[:, 0].reshape(obs.shape[:-1])

    def rollout_epsilon(self, ts: TrainState, env_steps: jax.Array) -> jax.Array:
        """Zero: PPO samples its policy (``choose_actions``), which reads no epsilon."""
        return jnp.zeros(())

    def learn(self, ts: TrainState, tr: Transitions, key: jax.Array) -> tuple[TrainState, dict]:
        """GAE over the rollout, then ``num_epochs`` shuffled passes of ``num_minibatches``
        steps of the policy and of the value network."""
        c, hp, loop = self.config, ts.hparams, self.loop
        critic = ts.algo_state.critic_params
        value = self.value_fn(critic, tr.obs)
        # every next observation through the value network: the final ones where the time
        # limit cut an episode bootstrap, and a rollout's last row needs its own pass anyway
        next_value = self.value_fn(critic, tr.next_obs)
        advantage, target = gae(
            tr.reward, tr.terminated, tr.done, value, next_value, hp.gamma, hp.td_lambda
        )
        apply = loop.learner_network.apply
        if c.memory:  # minibatches of envs: each env's sequence, its state at the start
            n = c.num_envs
            # the acting policy's log-probabilities: the parameters are still the rollout's,
            # each step read with the state it acted with
            old_log_prob = log_prob(apply(ts.params, tr.obs, tr.memory)[0], tr.action)
            steps = (tr.obs, tr.action, old_log_prob, advantage, value, target)
            data = (*(jnp.swapaxes(x, 0, 1) for x in steps), tr.done.T, tr.memory[0])
        else:
            n = c.steps_per_iteration
            obs, action = tr.obs.reshape(n, -1), tr.action.reshape(n)
            old_log_prob = log_prob(apply(ts.params, obs), action)
            steps = (advantage, value, target)
            data = (obs, action, old_log_prob, *(x.reshape(n) for x in steps))
        data = jax.lax.stop_gradient(data)
        actor_loss = self.minibatch_loss(ts)

        def critic_loss(params, batch):
            obs, old_value, target = batch
            v = self.value_fn(params, obs)
            loss = c.vf_coef * value_loss(v, old_value, target, c.clip_eps, c.clip_value)
            return loss, {"value": v}

        def minibatch(carry, rows):
            ts, total = carry
            obs, action, old_log_prob, advantage, old_value, target, *sequences = jax.tree.map(
                lambda x: x[rows], data
            )
            ts, actor_rows = loop.gradient_step(
                ts, (obs, action, old_log_prob, advantage, *sequences), actor_loss
            )
            state = ts.algo_state
            critic, critic_opt, critic_rows = loop.optimize(
                state.critic_params, state.critic_opt_state, hp, (obs, old_value, target),
                critic_loss,
            )  # fmt: skip
            ts = ts.replace(algo_state=PPOState(critic, critic_opt))
            # the losses as the step's gradients saw them (the parameters before it)
            v = critic_rows["value"]
            policy = -actor_rows["surrogate"].mean() - c.ent_coef * actor_rows["entropy"].mean()
            value = c.vf_coef * value_loss(v, old_value, target, c.clip_eps, c.clip_value)
            total = {
                "loss": total["loss"] + policy + value,
                "q_mean": total["q_mean"] + v.mean(),
                "q_max": jnp.maximum(total["q_max"], jnp.abs(v).max()),  # NaN stays NaN
            }
            return (ts, total), None

        def epoch(carry, k):
            order = pqn.shuffled_rows(k, n).reshape(c.num_minibatches, -1)
            unroll = loop.layout.unroll(c.num_minibatches)
            return jax.lax.scan(minibatch, carry, order, unroll=unroll)[0], None

        zero = jnp.zeros(())
        carry = (ts, {"loss": zero, "q_mean": zero, "q_max": zero})
        (ts, total), _ = jax.lax.scan(epoch, carry, jax.random.split(key, c.num_epochs))
        steps = c.num_epochs * c.num_minibatches
        aux = {
            "loss": total["loss"] / steps,
            "q_mean": total["q_mean"] / steps,  # the value network's mean value
            "q_max": total["q_max"],
            "updated": jnp.ones((), jnp.int32),
        }
        return ts, aux
