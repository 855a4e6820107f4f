"""Q-learning as one pure function: ``train = make_train(config); state, metrics = train(key)``.

The whole run is a ``jax.lax.scan`` over logging intervals, each a scan over iterations. An
iteration steps every env ``rollout_length`` times (acting epsilon-greedily with the online
network), then learns from what it collected, as the algorithm ``config.algo`` does it
(``jaxnav.algos``: the DQN's replay and target network, PQN's lambda-returns over a rollout).
The loop itself (env steps, gradient steps, the divergence guard, logging) is written once here.

The same compiled interval runs a whole training or a chunk of one (``Trainer.run``), so a run
cut into chunks for checkpoints computes exactly what an uncut one does. ``jit(vmap(train))``
trains several seeds (and several hyperparameter settings: ``HParams`` are pytree leaves) at once;
``jit_training`` compiles it as the CLI does, with the options it runs fastest with on a GPU.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from functools import cached_property, partial
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P

from jaxnav import backend, pretrained, sharding
from jaxnav.agents import dqn
from jaxnav.algos.base import LossFn, ProgramLayout, TrainState, Transitions
from jaxnav.config import HPARAMS, TrainConfig
from jaxnav.registration import make
from jaxnav.sharding import ENVS, SEEDS
from jaxnav.train import curriculum

METRIC_NAMES = (
    "env_steps",
    "episodes",
    "mean_return",
    "success_rate",
    "collision_rate",
    "mean_length",
    "loss",
    "q_mean",
    "epsilon",
    "lr",
)

# What the divergence guard watches: the acting step's Q-values and the TD loss every
# iteration, the parameters at the end of every logging interval (not every iteration: that
# would read every parameter once more per update; non-finite parameters show in the next
# iteration's Q-values anyway). ``TrainState.diverged`` becomes 1 + the index of the first
# non-finite one.
DIVERGENCE_QUANTITIES = ("q_values", "loss", "params")

# The fields of ``TrainState`` that held the DQN's target network and replay buffer (None for
# PQN) in checkpoints saved before ``algo_state`` held them (``legacy_checkpoint_layouts``)
LEGACY_ALGO_FIELDS = ("target_params", "buffer")

# XLA options every training program is compiled with (``jit_training``). On a GPU, XLA records a
# program's kernels into command buffers (CUDA graphs) that by default run them one after
# another; "CONCURRENT" gives the graph the kernels' data dependencies instead, so kernels that
# do not wait on each other run side by side (an env step's many small kernels, a backward
# pass's two products per layer). The same kernels compute the same values. The command
# buffers also take loops and conditionals (WHILE, CONDITIONAL) as CUDA graph nodes, so the
# device runs the epochs' and minibatches' trips without the host launching each one. The
# rollout's loop and the loop of iterations stay with the host: XLA copies their stacked rows
# by memcpys the host issues (docs/results-history.md: one graph for all was no faster). Options
# given here replace XLA's default list, which the first six entries repeat.
# Copy insertion by region analysis: XLA proves more of a loop's carried buffers free to update
# in place and copies fewer of them each trip; no arithmetic changes. Each option's effect:
# docs/performance.md. Other backends ignore XLA:GPU's options.
COMPILER_OPTIONS = {
    "xla_gpu_command_buffer_scheduling_mode": "CONCURRENT",
    "xla_gpu_enable_command_buffer": (
        "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,DYNAMIC_SLICE_FUSION,WHILE,CONDITIONAL"
    ),
    "xla_gpu_copy_insertion_use_region_analysis": True,
}


def jit_training(fun: Callable, **kwargs: Any) -> Any:
    """``jax.jit(fun, **kwargs)`` with ``COMPILER_OPTIONS``: how a training program (``train``,
    ``Trainer.run``, ``Trainer.init``) is compiled to run at its speed. For the top level only
    (JAX refuses options on a nested ``jit``): ``Trainer.sharded``'s programs, which
    ``jaxnav.programs`` exports, take them where they are compiled."""
    return jax.jit(fun, compiler_options=COMPILER_OPTIONS, **kwargs)


@struct.dataclass
class HParams:
    """Hyperparameters that may differ between runs of one compiled program (vmappable): a
    float32 array for each ``TrainConfig`` setting marked ``hparam``, in its order."""

    # checkpoints store these leaves by name: a setting marked hparam is one more of them
    __annotations__ = dict.fromkeys(HPARAMS, jax.Array)

    @classmethod
    def from_config(cls, config: TrainConfig) -> HParams:
        names = [f.name for f in cls.__dataclass_fields__.values()]
        return cls(**{n: jnp.asarray(getattr(config, n), jnp.float32) for n in names})


def program_layout(gpu_updates_unroll: int, platform: str | None = None) -> ProgramLayout:
    """How a training program is laid out on ``platform`` (JAX's default backend where None)
    for an algorithm whose gradient-step loops run ``gpu_updates_unroll`` steps a trip on a
    GPU (``Algorithm.gpu_updates_unroll``): the choices of ``jaxnav.backend``, which says why
    each is made."""
    return ProgramLayout(
        updates_unroll=backend.updates_unroll(gpu_updates_unroll, platform),
        returns_unrolled=backend.returns_unrolled(platform),
        target_update_select=backend.target_update_select(platform),
        optimizer_barrier=backend.optimizer_barrier(platform),
    )


class Trainer:
    """Builds the environment, network and the compiled pieces of a training run."""

    def __init__(self, config: TrainConfig):
        config.validate()
        self.config = config
        self.env, self.env_params = make(config.env, **config.env_kwargs)
        self.mesh = sharding.make_mesh(config.num_seeds, config.devices)
        self.network = dqn.QNetwork(
            num_actions=self.env.num_actions,
            hidden_sizes=tuple(config.hidden_sizes),
            dueling=config.dueling,
            onehot_sizes=self.env.obs_onehot_sizes,
            layer_norm=config.layer_norm,
            compute_dtype=config.compute_dtype,
            norm_impl=self.norm_impl(config),
            memory=config.memory,
        )
        # the network of the training program: over several devices its LayerNorm kernels
        # run on each device's rows; evaluation and export read ``network``, whose arrays are
        # not split over the mesh (one seed's episodes, a deployed policy)
        self.learner_network = (
            self.network.clone(mesh=self.mesh, rows_axis=ENVS)
            if config.devices > 1
            else self.network
        )
        self.obs_size = self.env.observation_space(self.env_params).shape[0]
        # how the program is laid out for this backend, resolved once (``program_layout``)
        self.layout = program_layout(config.algorithm.gpu_updates_unroll)
        self.algorithm = config.algorithm(self)
        self._check_memory()
        self._check_curriculum()

    @staticmethod
    def norm_impl(config: TrainConfig) -> str:
        """``QNetwork.norm_impl`` for ``config``: with ``fused_layer_norm``, the Pallas kernels
        where ``backend.layer_norm_kernels`` (over several GPUs, on each device's rows); else
        the jnp form of the kernels' math."""
        if not (config.layer_norm and config.fused_layer_norm):
            return "flax"
        return "pallas" if backend.layer_norm_kernels() else "fused"

    @property
    def network_input(self) -> dqn.InputSpec:
        """What the network reads: ``(obs_size, onehot_sizes)``."""
        return self.obs_size, self.network.onehot_sizes

    def _check_memory(self) -> None:
        """``ValueError`` for sizes whose replay buffers (PQN: rollouts), networks (params,
        target, two Adam moments) and per-interval metrics cannot fit in memory: on a GPU
        the replay and networks live in each device's memory, split over ``devices``, the
        metrics in the host's; on a CPU all in the host's. Refused before allocating, and
        before a run directory is created."""
        c = self.config
        first = dqn.input_size(*self.network_input)
        sizes = (first, *c.hidden_sizes, self.env.num_actions + 1)
        weights = sum((a + 1) * b for a, b in zip(sizes[:-1], sizes[1:], strict=False))
        weights += 3 * (c.hidden_sizes[-1] + c.memory + 2) * c.memory  # the GRU cell's
        obs_bytes = self.obs_size * jnp.dtype(self.env.observation_space().dtype).itemsize
        rows = c.algorithm.kept_rows(c)
        replay = rows * c.num_envs * (2 * obs_bytes + 4 * 4 + 4 * c.memory)
        # the host keeps every interval's metrics, [seeds, logs] per name (4-byte values),
        # and a copy of them while a checkpoint is written
        metrics = c.num_seeds * c.num_logs * len(METRIC_NAMES) * 4 * 2
        on_device = c.num_seeds * (replay + 4 * 4 * weights)
        device_limit = device_memory_limit()
        if device_limit is not None and on_device / c.devices > device_limit:
            raise ValueError(
                f"{self._kept_sizes()}, num_envs={c.num_envs}, num_seeds={c.num_seeds}: "
                f"replay and networks need about {on_device / c.devices / 2**30:.1f} GiB on "
                f"each of {c.devices} device(s), more than a device's "
                f"{device_limit / 2**30:.1f} GiB; use fewer envs, seeds or a smaller "
                "buffer, or more --devices"
            )
        need = metrics + (0 if device_limit is not None else on_device)
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        if need > have and metrics > need // 2:
            raise ValueError(
                f"total_timesteps={c.total_timesteps}, log_interval={c.log_interval}, "
                f"num_envs={c.num_envs}, num_seeds={c.num_seeds}: {c.num_logs:,} logging "
                f"intervals' metrics need about {metrics / 2**30:.1f} GiB, more than this "
                f"machine's {have / 2**30:.1f} GiB; log less often (a larger log_interval)"
            )
        if need > have:
            raise ValueError(
                f"{self._kept_sizes()}, num_envs={c.num_envs}, num_seeds={c.num_seeds}: "
                f"training needs about {need / 2**30:.1f} GiB, more than this machine's "
                f"{have / 2**30:.1f} GiB"
            )

    def _check_curriculum(self) -> None:
        """``ValueError`` (one line) for a curriculum over layouts on an env that does not draw
        its layouts by weight or has one layout only."""
        c = self.config
        if c.curriculum == "none":
            return
        if not self.env.weighted_layouts:
            raise ValueError(
                f"curriculum={c.curriculum}: {c.env} does not draw its layouts by weight"
            )
        if self.env.num_layouts(self.env_params) < 2:
            raise ValueError(
                f"curriculum={c.curriculum}: {c.env} has one layout, nothing to choose between "
                "(use a bank of several, e.g. GridMaze-Random-v0 or RobotNav-v0)"
            )

    def rollout_env_params(self, stats: curriculum.LayoutStats | None) -> Any:
        """The env params training steps with: ``env_params``, with a curriculum's statistics
        ``stats`` (``TrainState.curriculum``) the layouts' probabilities they give
        (``curriculum.layout_cdf``)."""
        if stats is None:
            return self.env_params
        return self.env_params.replace(layout_cdf=curriculum.layout_cdf(stats))

    @cached_property
    def init_params(self) -> Any:
        """The weights of ``config.init_from`` (flax's tree), None without one; ``ValueError``
        (one line naming it) for a policy that is not found or whose network, observation or
        actions are not this run's. Read when a run starts (``init``), not to evaluate or export
        a trained one."""
        name = self.config.init_from
        if not name:
            return None
        policy = pretrained.load_source(name, f"init_from={name!r}")
        c, net = self.config, policy.network
        theirs = {k: net.get(k, 0) for k in ("hidden_sizes", "dueling", "layer_norm", "memory")}
        ours = {k: getattr(c, k) for k in theirs}
        theirs["hidden_sizes"] = tuple(theirs["hidden_sizes"])
        for k in theirs:
            if theirs[k] != ours[k]:
                raise ValueError(
                    f"init_from={name!r}: its network has {k}={theirs[k]!r}, this run's "
                    f"{k}={ours[k]!r}"
                )
        onehot = net["onehot_sizes"]
        want = (net["obs_size"], None if onehot is None else tuple(onehot))
        if want != self.network_input:
            try:
                dqn.check_input_fits(c.env, self.network_input, want)
            except ValueError as e:
                raise ValueError(f"init_from={name!r}: {e}") from None
        actions = len(policy.metadata["actions"])
        if actions != self.env.num_actions:
            raise ValueError(
                f"init_from={name!r}: its policy has {actions} actions, --env {c.env} "
                f"{self.env.num_actions}"
            )
        return dqn.flax_params(policy.arrays, net)

    def _kept_sizes(self) -> str:
        """The fields that size what training keeps: the algorithm's transitions (a replay
        buffer, a rollout) and the network."""
        c = self.config
        return f"{c.algorithm.kept_sizes(c)}, hidden_sizes={','.join(map(str, c.hidden_sizes))}"

    # -- pieces ---------------------------------------------------------------------
    def default_hparams(self) -> HParams:
        return HParams.from_config(self.config)

    @property
    def total_updates(self) -> int:
        c = self.config
        learning_iterations = c.iterations - min(c.iterations, c.first_learning_iteration)
        return max(1, learning_iterations * c.updates_per_learning_iteration)

    def learning_rate(self, hp: HParams, updates: jax.Array) -> jax.Array:
        """Linear decay from ``lr`` to ``lr_end`` over the run's gradient steps."""
        return hp.lr + (hp.lr_end - hp.lr) * jnp.minimum(updates / self.total_updates, 1.0)

    def optimizer(self, hp: HParams) -> optax.GradientTransformation:
        """The optimizer of every network training updates: global-norm gradient clipping to
        ``max_grad_norm``, then Adam or SGD at the scheduled learning rate."""
        schedule = partial(self.learning_rate, hp)
        opt = optax.adam(schedule) if self.config.optimizer == "adam" else optax.sgd(schedule)
        # one flat vector instead of a leaf per layer: far fewer small kernels per update, which
        # bound PQN's many minibatch steps on a GPU (docs/results-history.md)
        chain = [optax.clip_by_global_norm(hp.max_grad_norm), opt]
        if self.layout.optimizer_barrier:
            chain.insert(0, optax.stateless(lambda g, _: jax.lax.optimization_barrier(g)))
        return optax.flatten(optax.chain(*chain))

    def init(self, key: jax.Array, hparams: HParams | None = None) -> TrainState:
        """A fresh training state; ``key`` alone decides every random choice of the run."""
        c = self.config
        hp = self.default_hparams() if hparams is None else hparams
        k_net, k_env, k_run = jax.random.split(key, 3)
        params = self.network.init(k_net, jnp.zeros((1, self.obs_size)))
        if self.init_params is not None:  # fine-tuning: the same tree, other values
            params = jax.tree.map(lambda a, b: b.astype(a.dtype), params, self.init_params)
        # the algorithm's key derived, not split off: the runs' other keys stay as they were
        k_algo = jax.random.fold_in(k_net, 1)
        stats = None
        if c.curriculum != "none":
            stats = curriculum.init(self.env.num_layouts(self.env_params))
        obs, env_state = jax.vmap(self.env.reset, in_axes=(0, None))(
            jax.random.split(k_env, c.num_envs), self.rollout_env_params(stats)
        )
        return TrainState(
            params=params,
            opt_state=self.optimizer(hp).init(params),
            algo_state=self.algorithm.init_state(params, k_algo, hp),
            env_state=env_state,
            obs=obs,
            episode_return=jnp.zeros(c.num_envs),
            episode_length=jnp.zeros(c.num_envs, jnp.int32),
            key=k_run,
            hparams=hp,
            diverged=jnp.zeros((), jnp.int32),
            diverged_at=jnp.zeros((), jnp.int32),
            memory=self.network.initial_memory(c.num_envs),
            curriculum=stats,
        )

    def epsilon(self, hp: HParams, env_steps: jax.Array) -> jax.Array:
        frac = jnp.clip(1.0 - env_steps / hp.eps_decay_steps, 0.0, 1.0)
        return hp.eps_end + (hp.eps_start - hp.eps_end) * frac

    def minibatch_loss(self, ts: TrainState) -> LossFn:
        """The algorithm's loss of one minibatch, ``loss(params, batch) -> (loss, rows)``
        (``rows``: ``dqn.regression_loss``'s diagnostics per row), as the training's gradient
        steps take it (``Algorithm.minibatch_loss``)."""
        return self.algorithm.minibatch_loss(ts)

    def gradient_step(
        self, ts: TrainState, batch: Any, loss_fn: Callable
    ) -> tuple[TrainState, dict]:
        """One optimizer step (gradient clipping, then Adam or SGD at the scheduled learning
        rate) on ``loss_fn(params, batch) -> (loss, rows)``, e.g. ``minibatch_loss(ts)``;
        returns the new state and ``rows``. Every update of every algorithm is this step
        (``optimize``)."""
        params, opt_state, rows = self.optimize(ts.params, ts.opt_state, ts.hparams, batch, loss_fn)
        return ts.replace(params=params, opt_state=opt_state), rows

    def optimize(
        self, params: Any, opt_state: Any, hp: HParams, batch: Any, loss_fn: LossFn
    ) -> tuple[Any, Any, dict]:
        """``gradient_step`` of any network's ``params`` and their ``optimizer(hp)`` state
        (the policy's, or a second network an algorithm keeps in ``algo_state``): the new
        params, optimizer state and ``loss_fn``'s rows."""
        # data parallel over a seed's devices: each computes the loss and gradient of its part
        # of the batch, and XLA sums the parts (the gradient averaging of ``sharded``)
        batch = jax.lax.with_sharding_constraint(batch, NamedSharding(self.mesh, P(ENVS)))
        grads, rows = jax.grad(loss_fn, has_aux=True)(params, batch)
        updates, opt_state = self.optimizer(hp).update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, rows

    def env_step(
        self,
        ts: TrainState,
        keys: tuple[jax.Array, jax.Array, jax.Array],
        eps: jax.Array,
        acting_params: Any,
    ) -> tuple[TrainState, tuple[Transitions, jax.Array, dict]]:
        """One step of every env, acting with ``acting_params`` (``ts.params``, or them as
        ``QNetwork.compute_params`` casts them) as the algorithm chooses
        (``Algorithm.choose_actions``: epsilon-greedy with ``eps``, or sampling a policy's
        logits): the new state, the transitions,
        whether the acting Q-values were finite, and episode statistics (per env: summed
        after the rollout, once an iteration)."""
        c = self.config
        k_act, k_eps, k_step = keys
        if self.network.memory:
            q, hidden = self.learner_network.apply(acting_params, ts.obs, ts.memory)
        else:
            q, hidden = self.learner_network.apply(acting_params, ts.obs), None
        action = self.algorithm.choose_actions(q, (k_act, k_eps), eps)
        env_params = self.rollout_env_params(ts.curriculum)
        obs, env_state, reward, terminated, truncated, info = jax.vmap(
            self.env.step, in_axes=(0, 0, 0, None)
        )(jax.random.split(k_step, c.num_envs), ts.env_state, action, env_params)
        done = terminated | truncated
        transitions = Transitions(
            ts.obs, action, reward, info["final_observation"], terminated, done, q.max(axis=-1),
            ts.memory,
        )  # fmt: skip
        ep_return = ts.episode_return + reward
        ep_length = ts.episode_length + 1
        # per env, not summed here: a sum over envs each step was a reduction into which XLA
        # fused (so recomputed) the env's collision test; summed over the rollout's stacked
        # rows it reads stored values
        stats = {
            "episodes": done,  # flags: a byte an env a step, counted by the sum
            "return_sum": jnp.where(done, ep_return, 0.0),
            "length_sum": jnp.where(done, ep_length, 0),
            "successes": done & info["goal_reached"],
            "collisions": done & info["collision"],
        }
        if ts.curriculum is not None:
            # the layout the step's episode ran in: the state before the step, not the one
            # auto-reset put in its place
            stats["layout"] = self.env.layout_index(ts.env_state)
        ts = ts.replace(
            env_state=env_state,
            obs=obs,
            episode_return=jnp.where(done, 0.0, ep_return),
            episode_length=jnp.where(done, 0, ep_length),
            memory=None if hidden is None else dqn.reset_memory(hidden, done),
        )
        return ts, (transitions, jnp.isfinite(q).all(), stats)

    def _iteration(self, ts: TrainState, it: jax.Array) -> tuple[TrainState, dict]:
        """One iteration of the algorithm (``Algorithm.iteration``: act, then learn), then
        the divergence guard and the iteration's statistics.

        ``it`` (the global iteration) comes from the scan, not the state, so it is unbatched
        under ``vmap`` and the DQN's ``cond`` skips the updates for real during warm-up.
        """
        c = self.config
        env_steps = it * c.steps_per_iteration
        ts, q_finite, stats, aux = self.algorithm.iteration(ts, env_steps)
        if ts.curriculum is not None:  # the episodes that ended in the iteration, by layout
            stats = dict(stats)
            layout = stats.pop("layout")
            stats_after = curriculum.update(
                ts.curriculum, layout, stats["episodes"], stats["successes"]
            )
            ts = ts.replace(curriculum=stats_after)
        stats = jax.tree.map(jnp.sum, stats)
        finite = q_finite.all() & jnp.isfinite(aux["q_mean"]) & jnp.isfinite(aux["q_max"])
        ts = self._flag_divergence(
            ts, [finite, jnp.isfinite(aux["loss"])], env_steps + c.steps_per_iteration
        )
        stats |= {
            "loss_sum": aux["loss"] * aux["updated"],
            "q_sum": aux["q_mean"] * aux["updated"],
            "updated": aux["updated"],
        }
        return ts, stats

    def _flag_divergence(
        self, ts: TrainState, finite: list[jax.Array], env_steps: jax.Array, first_code: int = 1
    ) -> TrainState:
        """Record the first non-finite quantity: ``finite[i]`` is DIVERGENCE_QUANTITIES[
        first_code - 1 + i]. The run keeps computing (a flag costs nothing under vmap; a
        skipped update would not); the caller stops after the interval and keeps its last
        checkpoint from before it."""
        finite = jnp.stack(finite)
        code = jnp.where(finite.all(), 0, jnp.argmin(finite) + first_code).astype(jnp.int32)
        first = (ts.diverged == 0) & (code > 0)
        return ts.replace(
            diverged=jnp.where(first, code, ts.diverged),
            diverged_at=jnp.where(first, env_steps, ts.diverged_at),
        )

    def _log_interval(self, ts: TrainState, log_index: jax.Array) -> tuple[TrainState, dict]:
        c = self.config
        first = log_index * c.iterations_per_log
        its = first + jnp.arange(c.iterations_per_log)
        ts, stats = jax.lax.scan(self._iteration, ts, its)
        s = jax.tree.map(lambda x: x.sum(), stats)
        episodes = jnp.maximum(s["episodes"], 1)
        updated = jnp.maximum(s["updated"], 1)
        env_steps = (first + c.iterations_per_log) * c.steps_per_iteration
        params_finite = jnp.stack([jnp.isfinite(x).all() for x in jax.tree.leaves(ts.params)])
        ts = self._flag_divergence(
            ts,
            [params_finite.all()],
            env_steps,
            first_code=DIVERGENCE_QUANTITIES.index("params") + 1,
        )
        updates_done = jnp.maximum(0, its[-1] + 1 - c.first_learning_iteration)
        metrics = {
            "env_steps": env_steps,
            "episodes": s["episodes"],
            "mean_return": s["return_sum"] / episodes,
            "success_rate": s["successes"] / episodes,
            "collision_rate": s["collisions"] / episodes,
            "mean_length": s["length_sum"] / episodes,
            "loss": s["loss_sum"] / updated,
            "q_mean": s["q_sum"] / updated,
            "epsilon": self.epsilon(ts.hparams, env_steps),
            "lr": self.learning_rate(ts.hparams, updates_done * c.updates_per_learning_iteration),
        }
        return ts, metrics

    # -- whole runs -----------------------------------------------------------------
    def run(
        self, ts: TrainState, first_log: int | jax.Array, num_logs: int
    ) -> tuple[TrainState, dict]:
        """``num_logs`` logging intervals starting at interval ``first_log``; metrics stacked."""
        logs = jnp.asarray(first_log) + jnp.arange(num_logs)
        return jax.lax.scan(self._log_interval, ts, logs)

    def train(self, key: jax.Array, hparams: HParams | None = None) -> tuple[TrainState, dict]:
        return self.run(self.init(key, hparams), 0, self.config.num_logs)

    def state_specs(self, state: TrainState) -> TrainState:
        """``PartitionSpec``s of a seed-batched ``state`` (``sharding.state_specs``, with
        the algorithm's for its ``algo_state``)."""
        algo_specs = self.algorithm.state_specs(state.algo_state, P(SEEDS))
        return sharding.state_specs(state, algo_specs)

    def legacy_checkpoint_layouts(
        self, state_like: TrainState
    ) -> list[tuple[dict[str, Any], Callable[[dict[str, Any]], TrainState]]]:
        """``(layout, upgrade)`` of each earlier layout a checkpoint of ``state_like`` may have
        been saved in, newest first: ``layout`` is ``state_like`` as those were saved, and
        ``upgrade`` turns a state restored in it into a ``TrainState``. A run without a
        curriculum may have a checkpoint saved before ``TrainState.curriculum`` (its other
        fields, a dict); one without memory also before ``TrainState.memory`` (the fields
        older than both), or before the algorithms kept their own state in ``algo_state`` (a
        dict of the other fields with ``LEGACY_ALGO_FIELDS`` in place of ``algo_state``, None
        where the algorithm has no such field; not for an algorithm added since, whose state
        that layout cannot hold). A run with a curriculum has none: it is newer than all."""
        if state_like.curriculum is not None:
            return []
        restore = lambda saved: TrainState(**saved)  # noqa: E731 (the missing fields are None)
        fields = [n for n in state_like.__dataclass_fields__ if n != "curriculum"]
        layouts = [({n: getattr(state_like, n) for n in fields}, restore)]
        if state_like.memory is not None:
            return layouts
        fields = [n for n in fields if n != "memory"]
        layouts.append(({n: getattr(state_like, n) for n in fields}, restore))
        algo_like = state_like.algo_state
        if not set(getattr(algo_like, "__dataclass_fields__", ())) <= set(LEGACY_ALGO_FIELDS):
            return layouts
        shared = {n: getattr(state_like, n) for n in fields if n != "algo_state"}
        layout = {**shared, **{n: getattr(algo_like, n, None) for n in LEGACY_ALGO_FIELDS}}

        def upgrade(saved: dict[str, Any]) -> TrainState:
            kept = [n for n in LEGACY_ALGO_FIELDS if hasattr(algo_like, n)]
            algo_state = algo_like and algo_like.replace(**{n: saved[n] for n in kept})
            return TrainState(**{n: saved[n] for n in shared}, algo_state=algo_state)

        return [*layouts, (layout, upgrade)]

    def sharded(self, keys: jax.Array) -> tuple[Callable, Callable, Any]:
        """``(init, interval, state_like)`` for the seeds of ``keys`` on ``self.mesh``:
        ``init(keys)``, jitted, is the seed-batched state (abstract: ``state_like``) laid out
        by ``sharding.state_specs``; ``interval(state, log)``, jitted, runs logging interval
        ``log`` and returns the state (donated) and that interval's metrics, [seeds, 1] each,
        replicated on every device and host.

        The program is the one-device program; XLA partitions it (GSPMD) from the layout of
        the state and the batch constraint in ``gradient_step``, so a sharded run computes what one
        device does, up to the order of floating-point sums. Compile them with
        ``COMPILER_OPTIONS`` (``jaxnav.programs`` does) to run at full speed on a GPU."""
        state_like = jax.eval_shape(jax.vmap(self.init), keys)
        specs = self.state_specs(state_like)
        state_sharding = sharding.shardings(self.mesh, specs)
        init = jax.jit(jax.vmap(self.init, spmd_axis_name=SEEDS), out_shardings=state_sharding)
        state_like = jax.tree.map(
            lambda x, s: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=s),
            state_like,
            state_sharding,
        )

        def interval(ts: TrainState, log: jax.Array) -> tuple[TrainState, dict]:
            if len(keys) == 1:
                # one seed is compiled without the seed axis: XLA's CPU backend reduces
                # LayerNorm's gradients over the middle axis of [1, batch, width] slowly (PQN
                # trained 1.26x slower that way); on a GPU the two programs run alike
                # (train_vmap_* in docs/results-history.md)
                ts, metrics = self.run(jax.tree.map(lambda x: x[0], ts), log, 1)
                return jax.tree.map(lambda x: x[None], (ts, metrics))
            return jax.vmap(lambda ts: self.run(ts, log, 1), spmd_axis_name=SEEDS)(ts)

        interval = jax.jit(
            interval,
            in_shardings=(state_sharding, None),
            out_shardings=(state_sharding, NamedSharding(self.mesh, P())),
            donate_argnums=0,
        )
        return init, interval, state_like

    def greedy_policy(self, params: Any) -> Callable[[jax.Array, jax.Array], jax.Array] | Any:
        """The greedy policy of ``params``: ``(key, obs) -> action``, or with memory a
        ``dqn.RecurrentPolicy`` whose state is the hidden state (zeros at an episode's start).
        """
        net = self.network
        if not net.memory:
            return lambda key, obs: jnp.argmax(net.apply(params, obs), axis=-1)

        def step(hidden: jax.Array, key: jax.Array, obs: jax.Array) -> tuple:
            q, hidden = net.apply(params, obs, hidden)
            return hidden, jnp.argmax(q, axis=-1)

        return dqn.RecurrentPolicy(net.initial_memory, step)


def device_memory_limit() -> int | None:
    """Bytes one accelerator can allocate (its first local device's), or None on a CPU,
    whose arrays live in the host's memory."""
    device = jax.local_devices()[0]
    if device.platform == "cpu":
        return None
    stats = device.memory_stats() or {}
    return stats.get("bytes_limit")


def make_train(config: TrainConfig) -> Callable[..., tuple[TrainState, dict]]:
    """PureJaxRL-style: ``train(key, hparams=None) -> (final TrainState, metrics per log)``.

    No host callback inside: progress is printed between logging intervals by the caller
    (``Trainer.run``), so the compiled program can be stored in JAX's persistent cache."""
    return Trainer(config).train
