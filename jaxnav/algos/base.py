"""The interface every training algorithm implements, and the state the shared loop carries.

``jaxnav.train.Trainer`` is the one training loop: it steps the envs, takes gradient steps,
guards against divergence and logs. An algorithm (``jaxnav.algos.ALGOS``) is a subclass of
``Algorithm`` bound to that loop: what it adds to the training state (``TrainState.algo_state``),
how an iteration acts and learns, its derived sizes and its config's validation. Adding an
algorithm is its module, its presets (``jaxnav.presets``) and its tests.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Protocol

import jax
import jax.numpy as jnp
from flax import struct

from jaxnav.sharding import mesh_shape


@struct.dataclass
class Transitions:
    """What a rollout collected, laid out [time, env, ...]."""

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array  # the final observation where the episode ended
    terminated: jax.Array
    done: jax.Array
    value: jax.Array  # the largest output of the acting pass (max_a Q(obs, a))
    # with memory: the hidden state the acting pass read [time, env, memory]; else None
    memory: Any = None


@struct.dataclass
class TrainState:
    params: Any
    opt_state: Any
    algo_state: Any  # the algorithm's own pytree (the DQN's target network and replay buffer)
    env_state: Any
    obs: jax.Array  # [N, D]
    episode_return: jax.Array  # [N] running return of each env's current episode
    episode_length: jax.Array  # [N]
    key: jax.Array
    hparams: Any  # ``jaxnav.train.HParams``
    # divergence guard: set once, at the first iteration where a watched quantity is NaN/Inf
    diverged: jax.Array  # int32, see ``jaxnav.train.DIVERGENCE_QUANTITIES``
    diverged_at: jax.Array  # int32, env steps when it was seen (0 if not diverged)
    # with memory (``TrainConfig.memory``): each env's hidden state [N, memory] for its next
    # step, zeros where an episode starts; None without (checkpoints keep their layout)
    memory: Any = None
    # with a curriculum (``TrainConfig.curriculum``): its per-layout statistics
    # (``jaxnav.train.curriculum.LayoutStats``); None without
    curriculum: Any = None


# gradient steps per iteration, at most (a scan of them is compiled into every iteration)
MAX_UPDATES = 65536

LossFn = Callable[[Any, Any], tuple[jax.Array, dict]]  # (params, batch) -> (loss, rows)


@dataclasses.dataclass(frozen=True)
class ProgramLayout:
    """How the training program is laid out for the backend it runs on (``Loop.layout``,
    resolved by ``jaxnav.train.program_layout`` from ``jaxnav.backend``, which says why each
    choice is made). Each changes how XLA schedules the same operations, never the values
    computed."""

    # gradient steps one trip of a gradient-step loop runs, at most (``unroll``)
    updates_unroll: int = 1
    # PQN's lambda-returns as straight-line code (``agents.pqn.lambda_returns``'s ``unrolled``)
    returns_unrolled: bool = False
    # the DQN's target update a select over the parameters, else a cond
    target_update_select: bool = False
    # the flat gradient written out once before the optimizer reads it
    optimizer_barrier: bool = False

    def unroll(self, steps: int) -> int:
        """The ``unroll`` of a scan over ``steps`` gradient steps."""
        return min(steps, self.updates_unroll)


class Loop(Protocol):
    """What an algorithm reads of the training loop (``jaxnav.train.Trainer``)."""

    config: Any  # ``jaxnav.config.TrainConfig``
    env: Any
    env_params: Any
    network: Any  # ``agents.dqn.QNetwork``: Q-values, or a policy's logits
    learner_network: Any  # the same, as the training program runs it (over devices)
    obs_size: int
    layout: ProgramLayout  # how the program is laid out for the backend it runs on

    def env_step(
        self, ts: TrainState, keys: tuple[jax.Array, jax.Array, jax.Array], eps: jax.Array,
        acting_params: Any,
    ) -> tuple[TrainState, tuple[Transitions, jax.Array, dict]]: ...  # fmt: skip

    def gradient_step(
        self, ts: TrainState, batch: Any, loss_fn: LossFn
    ) -> tuple[TrainState, dict]: ...

    def optimize(
        self, params: Any, opt_state: Any, hp: Any, batch: Any, loss_fn: LossFn
    ) -> tuple[Any, Any, dict]: ...

    def optimizer(self, hp: Any) -> Any: ...  # ``optax.GradientTransformation``

    def epsilon(self, hp: Any, env_steps: jax.Array) -> jax.Array: ...


class Algorithm:
    """An algorithm of the training loop. The class methods read a ``TrainConfig`` alone
    (``TrainConfig.validate`` and its derived sizes call them); an instance is bound to a
    ``Loop`` and builds the algorithm's part of the compiled training."""

    # the config field that sets ``minibatch_size``, as messages name it
    minibatch_field = "minibatch_size"
    # what the network's outputs are, as exported policies describe them
    outputs = "Q-values"
    # how training acts (``choose_actions``), as progress lines name its episodes
    acting = "eps-greedy"
    # whether it trains a recurrent network (``TrainConfig.memory``)
    recurrent = False
    # what it is, as the help of ``--algo`` says
    summary = ""
    # gradient steps one trip of its gradient-step loops runs on a GPU, at most
    # (``ProgramLayout.updates_unroll``, which the loop resolves from it)
    gpu_updates_unroll = 1

    def __init__(self, loop: Loop):
        self.loop = loop
        self.config = loop.config

    # -- the config alone -----------------------------------------------------------
    @classmethod
    def validate(cls, config: Any) -> None:
        """``ValueError`` (one line) naming the first value of ``config`` (a ``TrainConfig``,
        whose own checks passed) that this algorithm cannot train with."""

    @classmethod
    def first_learning_iteration(cls, config: Any) -> int:
        """The first iteration that takes gradient steps."""
        return 0

    @classmethod
    def updates_per_learning_iteration(cls, config: Any) -> int:
        """Gradient steps of an iteration that learns."""
        raise NotImplementedError

    @classmethod
    def minibatch_size(cls, config: Any) -> int:
        """Transitions per gradient step."""
        raise NotImplementedError

    @classmethod
    def kept_rows(cls, config: Any) -> int:
        """Rows of ``num_envs`` transitions training keeps in memory (a replay buffer, a
        rollout)."""
        raise NotImplementedError

    @classmethod
    def kept_sizes(cls, config: Any) -> str:
        """The fields that size what ``kept_rows`` keeps, e.g. "buffer_size=100000"."""
        raise NotImplementedError

    # -- the training program --------------------------------------------------------
    def init_state(self, params: Any, key: jax.Array, hparams: Any) -> Any:
        """The algorithm's part of a fresh ``TrainState`` (``algo_state``) for the network's
        initial ``params``, with ``key`` for its own random choices (e.g. a second network's
        initialization) and the run's ``hparams``; None where it keeps nothing of its own."""
        return None

    def choose_actions(
        self, outputs: jax.Array, keys: tuple[jax.Array, jax.Array], eps: jax.Array
    ) -> jax.Array:
        """The actions [N] of an acting pass's ``outputs`` [N, num_actions]
        (``Loop.env_step``): by default epsilon-greedy in the Q-values, a uniformly random
        action (key ``keys[0]``) with probability ``eps`` (key ``keys[1]``)."""
        k_act, k_eps = keys
        n, num_actions = outputs.shape
        explore = jax.random.uniform(k_eps, (n,)) < eps
        random_action = jax.random.randint(k_act, (n,), 0, num_actions)
        return jnp.where(explore, random_action, jnp.argmax(outputs, axis=-1))

    def state_specs(self, algo_state: Any, per_seed: Any) -> Any:
        """``PartitionSpec``s of a seed-batched ``algo_state`` (``jaxnav.sharding``): by
        default ``per_seed`` for every array."""
        return jax.tree.map(lambda _: per_seed, algo_state)

    def minibatch_loss(self, ts: TrainState) -> LossFn:
        """The loss of one minibatch as the gradient steps take it: ``loss(params, batch) ->
        (loss, rows)``, ``rows`` the per-row diagnostics of ``agents.dqn.regression_loss``."""
        raise NotImplementedError

    def iteration(
        self, ts: TrainState, env_steps: jax.Array
    ) -> tuple[TrainState, jax.Array, dict, dict]:
        """One iteration from ``env_steps`` env steps done: act (``Loop.env_step``) and learn
        (``Loop.gradient_step``) with the keys it splits from ``ts.key``. Returns the state
        (its ``key`` advanced), whether the acting Q-values were finite, the episode
        statistics of every env step (per env, summed by the loop) and the learning's
        diagnostics: ``loss``, ``q_mean``, ``q_max`` and ``updated`` (1 if it took gradient
        steps)."""
        raise NotImplementedError


class RolloutAlgorithm(Algorithm):
    """An algorithm that learns from each rollout of ``num_envs x rollout_length`` steps in
    ``num_epochs`` passes of ``num_minibatches`` gradient steps (PQN, PPO): their sizes and
    check, written once. With ``memory`` a minibatch is the whole rollouts of some envs."""

    recurrent = True

    @classmethod
    def validate(cls, config: Any) -> None:
        if config.memory and config.num_envs % config.num_minibatches:
            raise ValueError(
                f"num_minibatches={config.num_minibatches} does not divide num_envs="
                f"{config.num_envs}: with memory={config.memory} a minibatch is whole "
                "sequences of envs"
            )
        shards = mesh_shape(config.num_seeds, config.devices)[1]
        if config.memory and (config.num_envs // config.num_minibatches) % shards:
            raise ValueError(
                f"num_minibatches={config.num_minibatches}: with memory={config.memory} a "
                f"minibatch's {config.num_envs // config.num_minibatches} envs are not a "
                f"multiple of the {shards} devices each seed's envs are split over "
                f"(devices={config.devices}, num_seeds={config.num_seeds})"
            )
        if config.steps_per_iteration % config.num_minibatches:
            raise ValueError(
                f"num_minibatches={config.num_minibatches} does not divide the "
                f"num_envs * rollout_length = {config.steps_per_iteration} transitions of a "
                "rollout"
            )

    @classmethod
    def updates_per_learning_iteration(cls, config: Any) -> int:
        return config.num_epochs * config.num_minibatches

    @classmethod
    def minibatch_size(cls, config: Any) -> int:
        return config.steps_per_iteration // config.num_minibatches

    @classmethod
    def kept_rows(cls, config: Any) -> int:
        return config.rollout_length

    @classmethod
    def kept_sizes(cls, config: Any) -> str:
        return f"rollout_length={config.rollout_length}"

    def rollout_epsilon(self, ts: TrainState, env_steps: jax.Array) -> jax.Array:
        """The epsilon a rollout acts with (``Loop.epsilon``, PQN's epsilon-greedy)."""
        return self.loop.epsilon(ts.hparams, env_steps)

    def iteration(
        self, ts: TrainState, env_steps: jax.Array
    ) -> tuple[TrainState, jax.Array, dict, dict]:
        """A rollout of every env (``choose_actions`` with ``rollout_epsilon``), then
        ``learn``."""
        c, loop = self.config, self.loop
        key, k_roll, k_learn = jax.random.split(ts.key, 3)
        eps = self.rollout_epsilon(ts, env_steps)
        # the parameters do not change within a rollout: cast once for its acting passes
        acting = loop.network.compute_params(ts.params)
        ts, (tr, finite, stats) = jax.lax.scan(
            lambda ts, k: loop.env_step(ts, tuple(jax.random.split(k, 3)), eps, acting),
            ts,
            jax.random.split(k_roll, c.rollout_length),
        )
        ts, aux = self.learn(ts.replace(key=key), tr, k_learn)
        return ts, finite, stats, aux

    def learn(self, ts: TrainState, tr: Transitions, key: jax.Array) -> tuple[TrainState, dict]:
        """Learn from the rollout ``tr`` (laid out [time, env]) with ``key``."""
        raise NotImplementedError
