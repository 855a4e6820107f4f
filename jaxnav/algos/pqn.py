"""PQN (Gallici et al. 2024): every iteration is a rollout of ``rollout_length`` steps of
every env, lambda-returns from the online network (``agents.pqn.lambda_returns``), then
``num_epochs`` shuffled passes of ``num_minibatches`` gradient steps over it; no replay, no
target network (the LayerNorm network keeps the bootstrapped targets from diverging).

With ``memory`` (a recurrent network) the targets come from the hidden states the rollout
acted with, and a minibatch is the whole rollouts of some envs: the gradient step runs the
network over each env's sequence from its hidden state at the rollout's start, reset where
an episode ends (``agents.dqn.unroll``), as PQN-RNN (purejaxql) does."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxnav.agents import dqn, pqn
from jaxnav.algos.base import LossFn, RolloutAlgorithm, TrainState, Transitions


class PQN(RolloutAlgorithm):
    """Lambda-returns over rollouts of many envs; keeps nothing beyond the shared state."""

    summary = "lambda-returns over rollouts of many envs, no replay"
    gpu_updates_unroll = 16

    def minibatch_loss(self, ts: TrainState) -> LossFn:
        """The regression on ``(obs [B, D], action [B], target [B])``, the target a
        lambda-return; with memory on whole sequences of B envs, ``(obs [B, T, D], action
        [B, T], target [B, T], done [B, T], hidden [B, H])``, ``hidden`` their state at the
        sequences' start."""
        c, apply = self.config, self.loop.learner_network.apply
        if not c.memory:

            def loss_fn(params, batch):
                obs, action, target = batch
                return dqn.regression_loss(params, apply, obs, action, target, c.loss)

            return loss_fn

        def sequence_loss(params, batch):
            obs, action, target, done, hidden = batch
            q = lambda p, o: dqn.sequence_outputs(apply, p, o, hidden, done)  # noqa: E731
            rows = lambda x: x.reshape(-1)  # noqa: E731
            return dqn.regression_loss(params, q, obs, rows(action), rows(target), c.loss)

        return sequence_loss

    def next_values(self, params: Any, tr: Transitions, last_obs: jax.Array) -> jax.Array:
        """``max_a Q(s', a)`` for every step of rollout ``tr`` [T, N], the observation after
        the step (``last_obs`` after the last one; the final observation where an episode
        ended), as one forward pass over ``tr.next_obs`` would give them.

        The acting pass of step t + 1 already valued the observation after step t unless the
        episode ended there (it then acted on the reset's observation): values are taken from
        it, and only ``last_obs`` and the final observations of episodes cut by the time
        limit go through the network again (terminated ones do not bootstrap). The time
        limit cuts an env at most once in ``max_steps_in_episode`` steps, so, in a rollout
        no longer than that, at most once: one pass over one row an env. Longer rollouts (or
        an env cut twice) take one pass over every next observation. With memory every next
        observation goes through the network, with the state after its step."""
        network = self.loop.learner_network
        if tr.memory is not None:
            # each next observation read with the hidden state after its step (reset only
            # after it): the acting pass's states give them all in two passes, no loop
            after = network.apply(params, tr.obs, tr.memory)[1]
            return network.apply(params, tr.next_obs, after)[0].max(axis=-1)
        q_max = lambda obs: network.apply(params, obs).max(axis=-1)  # noqa: E731
        every = lambda _: q_max(tr.next_obs)  # noqa: E731
        if tr.reward.shape[0] > int(self.loop.env_params.max_steps_in_episode):
            return every(None)
        cut = tr.done & ~tr.terminated

        def once(_) -> jax.Array:
            step = jnp.argmax(cut, axis=0)  # each env's cut step, 0 if none
            final = q_max(tr.next_obs[step, jnp.arange(cut.shape[1])])
            following = jnp.concatenate([tr.value[1:], q_max(last_obs)[None]])
            return jnp.where(cut, final, following)

        return jax.lax.cond((cut.sum(axis=0) <= 1).all(), once, every, None)

    def learn(self, ts: TrainState, tr: Transitions, key: jax.Array) -> tuple[TrainState, dict]:
        """Lambda-returns of the rollout from the current network, then ``num_epochs``
        shuffled passes of ``num_minibatches`` gradient steps over it."""
        c, hp, loop = self.config, ts.hparams, self.loop
        next_value = self.next_values(ts.params, tr, ts.obs)
        targets = pqn.lambda_returns(
            tr.reward,
            tr.terminated,
            tr.done,
            next_value,
            hp.gamma,
            hp.td_lambda,
            unrolled=loop.layout.returns_unrolled,
        )
        n = c.steps_per_iteration
        targets = jax.lax.stop_gradient(targets)
        if c.memory:  # minibatches of envs: each env's sequence, its state at the start
            n = c.num_envs
            env_major = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731
            data = (*map(env_major, (tr.obs, tr.action, targets, tr.done)), tr.memory[0])
        else:
            data = (tr.obs.reshape(n, -1), tr.action.reshape(n), targets.reshape(n))
        loss_fn = self.minibatch_loss(ts)

        def minibatch(carry, rows):
            ts, total = carry
            ts, diagnostics = loop.gradient_step(ts, jax.tree.map(lambda x: x[rows], data), loss_fn)
            return (ts, dqn.diagnostics_add(total, diagnostics)), None

        def epoch(carry, k):
            # each step gathers its own rows: no shuffled copy of the whole rollout an epoch
            order = pqn.shuffled_rows(k, n).reshape(c.num_minibatches, -1)
            unroll = loop.layout.unroll(c.num_minibatches)
            return jax.lax.scan(minibatch, carry, order, unroll=unroll)[0], None

        carry = (ts, dqn.diagnostics_init(self.minibatch_size(c)))
        (ts, total), _ = jax.lax.scan(epoch, carry, jax.random.split(key, c.num_epochs))
        aux = dqn.diagnostics_means(total, c.num_epochs * c.num_minibatches)
        return ts, aux | {"updated": jnp.ones((), jnp.int32)}
