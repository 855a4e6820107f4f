"""The DQN (the paper's): every iteration steps each env once, writes the step into a replay
buffer and, once ``learning_starts`` env steps are done, takes ``updates_per_iteration`` =
``replay_ratio * num_envs / batch_size`` gradient steps on replay samples against a target
network (``replay_ratio`` sampled transitions per env step).

The network, replay buffer, TD loss and targets are ``jaxnav.agents.dqn``'s.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.sharding import PartitionSpec as P

from jaxnav.agents import dqn
from jaxnav.algos.base import MAX_UPDATES, Algorithm, LossFn, TrainState, Transitions
from jaxnav.sharding import ENVS, SEEDS


@struct.dataclass
class DQNState:
    """What the DQN adds to the training state."""

    target_params: Any
    buffer: dqn.ReplayBuffer


class DQN(Algorithm):
    """Replay and a target network (``dueling`` and ``double`` flags: the paper's agents)."""

    minibatch_field = "batch_size"
    summary = "the paper's: replay and a target network"
    gpu_updates_unroll = 2

    @classmethod
    def validate(cls, config: Any) -> None:
        c = config
        if c.rollout_length != 1:
            raise ValueError(
                f"rollout_length={c.rollout_length}: algo=dqn steps every env once per "
                "iteration (use replay_ratio for the gradient steps per env step)"
            )
        if c.batch_size > c.buffer_size:
            raise ValueError(
                f"batch_size={c.batch_size} is larger than buffer_size={c.buffer_size}"
            )
        if c.buffer_size < c.num_envs * c.n_step:
            raise ValueError(
                f"buffer_size={c.buffer_size} must hold n_step={c.n_step} steps of "
                f"num_envs={c.num_envs} envs (>= {c.num_envs * c.n_step})"
            )
        if c.learning_start_steps >= c.total_timesteps:
            raise ValueError(
                f"learning_starts={c.learning_starts} with num_envs={c.num_envs} and "
                f"n_step={c.n_step} waits {c.learning_start_steps} env steps, not below "
                f"total_timesteps={c.total_timesteps}: no update would ever run"
            )
        updates = c.updates_per_iteration  # ValueError unless a whole number >= 1
        if updates > MAX_UPDATES:
            raise ValueError(
                f"replay_ratio={c.replay_ratio!r} with num_envs={c.num_envs} and "
                f"batch_size={c.batch_size} gives {updates} gradient steps per iteration, "
                f"more than {MAX_UPDATES}; use a larger batch_size or a smaller replay_ratio"
            )

    @classmethod
    def first_learning_iteration(cls, config: Any) -> int:
        """The first iteration whose env-step count reaches ``learning_starts``, and at least
        the ``n_step``-th, when replay holds an n-step transition."""
        return max(-(-config.learning_starts // config.num_envs), config.n_step)

    @classmethod
    def updates_per_learning_iteration(cls, config: Any) -> int:
        return config.updates_per_iteration

    @classmethod
    def minibatch_size(cls, config: Any) -> int:
        return config.batch_size

    @classmethod
    def kept_rows(cls, config: Any) -> int:
        return config.buffer_rows

    @classmethod
    def kept_sizes(cls, config: Any) -> str:
        return f"buffer_size={config.buffer_size}"

    def init_state(self, params: Any, key: jax.Array, hparams: Any) -> DQNState:
        c, loop = self.config, self.loop
        obs_dtype = loop.env.observation_space().dtype
        buffer = dqn.buffer_init(c.buffer_rows, c.num_envs, loop.obs_size, obs_dtype)
        return DQNState(target_params=params, buffer=buffer)

    def state_specs(self, algo_state: DQNState, per_seed: Any) -> DQNState:
        """Replay arrays are [seed, time, env, ...]: split over seeds and envs."""
        buffer = algo_state.buffer
        replay = P(SEEDS, None, ENVS)
        return DQNState(
            target_params=jax.tree.map(lambda _: per_seed, algo_state.target_params),
            buffer=buffer.replace(
                **{
                    name: replay if getattr(buffer, name).ndim >= 3 else per_seed
                    for name in buffer.__dataclass_fields__
                }
            ),
        )

    def minibatch_loss(self, ts: TrainState) -> LossFn:
        """The TD loss against ``ts``'s target network on a ``dqn.buffer_sample`` batch."""
        c, apply = self.config, self.loop.learner_network.apply
        target_params = ts.algo_state.target_params
        return lambda params, batch: dqn.td_loss(
            params, target_params, apply, batch, c.double, c.loss
        )

    def iteration(
        self, ts: TrainState, env_steps: jax.Array
    ) -> tuple[TrainState, jax.Array, dict, dict]:
        """One step of every env (random actions until learning starts), then ``learn``."""
        c, loop = self.config, self.loop
        key, k_act, k_eps, k_step, k_learn = jax.random.split(ts.key, 5)
        eps = jnp.where(
            env_steps >= c.learning_start_steps, loop.epsilon(ts.hparams, env_steps), 1.0
        )
        ts, collected = loop.env_step(ts, (k_act, k_eps, k_step), eps, ts.params)
        tr, q_finite, stats = jax.tree.map(lambda x: x[None], collected)
        ts, aux = self.learn(ts.replace(key=key), tr, env_steps, k_learn)
        return ts, q_finite, stats, aux

    def learn(
        self, ts: TrainState, tr: Transitions, env_steps: jax.Array, key: jax.Array
    ) -> tuple[TrainState, dict]:
        """Write the step into replay; once ``learning_starts`` is passed, gradient steps and
        the target network's update."""
        c, hp, loop = self.config, ts.hparams, self.loop
        step = jax.tree.map(lambda x: x[0], tr)
        buffer = dqn.buffer_add(
            ts.algo_state.buffer, step.obs, step.action, step.reward, step.next_obs,
            step.terminated, step.done,
        )  # fmt: skip
        ts = ts.replace(algo_state=ts.algo_state.replace(buffer=buffer))
        learning = env_steps >= c.learning_start_steps

        # The target network is updated when env steps cross a multiple of the period
        # (rejax-style), at the resolution of gradient steps: the iteration's u steps each
        # stand for num_envs / u of its env steps, and a step whose share crosses a multiple
        # updates it. So target_update_period means the same at any num_envs, also where one
        # iteration of many envs spans several periods. Env steps and the offsets are
        # unbatched under vmap, so on a CPU the cond skips the parameter-sized work for real.
        period, u = c.target_update_period, c.updates_per_iteration
        ends = (np.arange(1, u + 1, dtype=np.int64) * c.num_envs // u).astype(np.int32)
        starts = np.concatenate([[0], ends[:-1]]).astype(np.int32)

        def with_target(ts: TrainState, target: Any) -> TrainState:
            return ts.replace(algo_state=ts.algo_state.replace(target_params=target))

        def updated_target(ts: TrainState) -> Any:
            return dqn.polyak(ts.algo_state.target_params, ts.params, hp.tau)

        def update(carry, xs):
            ts, total = carry
            batch, start, end = xs
            ts, rows = loop.gradient_step(ts, batch, self.minibatch_loss(ts))
            crossed = (env_steps + end) // period > (env_steps + start) // period
            if loop.layout.target_update_select:
                target = jax.tree.map(
                    partial(jnp.where, crossed), updated_target(ts), ts.algo_state.target_params
                )
                ts = with_target(ts, target)
            else:
                ts = jax.lax.cond(
                    crossed,
                    lambda ts: with_target(ts, updated_target(ts)),
                    lambda ts: ts,
                    ts,
                )
            return (ts, dqn.diagnostics_add(total, rows)), None

        def updates(ts):
            # the iteration's batches sampled at once: replay does not change during its
            # gradient steps, and sampling inside each one put it first in every step's chain
            # of kernels (the same samples: one key a step either way)
            buffer = ts.algo_state.buffer
            batches = jax.vmap(
                lambda k: dqn.buffer_sample(buffer, k, c.batch_size, c.n_step, hp.gamma)
            )(jax.random.split(key, u))
            total = dqn.diagnostics_init(c.batch_size)
            xs = (batches, starts, ends)
            (ts, total), _ = jax.lax.scan(update, (ts, total), xs, unroll=loop.layout.unroll(u))
            aux = dqn.diagnostics_means(total, u)
            return ts, aux | {"updated": jnp.ones((), jnp.int32)}

        def no_updates(ts):
            zeros = {name: jnp.zeros(()) for name in dqn.DIAGNOSTICS}
            return ts, zeros | {"updated": jnp.zeros((), jnp.int32)}

        ts, aux = jax.lax.cond(learning, updates, no_updates, ts)
        return ts, aux
