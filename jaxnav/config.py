"""Training configuration: one frozen dataclass, validated before anything compiles."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax

from jaxnav.agents.dqn import COMPUTE_DTYPES
from jaxnav.algos import ALGOS as ALGORITHMS
from jaxnav.algos.base import MAX_UPDATES, Algorithm
from jaxnav.presets import default_algo, train_defaults
from jaxnav.registration import env_config
from jaxnav.sharding import mesh_shape

# step counters are int32 inside the compiled loop; keep a margin below 2^31
MAX_STEPS = 2_000_000_000
ALGOS = tuple(ALGORITHMS)  # the names ``algo`` takes


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Defaults reproduce the paper's grid experiment (Sec. IV-A) on a laptop CPU.

    Sizes count env steps (transitions of one env) unless named otherwise.
    """

    env: str = "GridMaze-v0"
    env_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    # "dqn": the paper's (dueling, double) DQN with replay and a target network; "pqn":
    # lambda-returns over rollouts of many envs, no replay, no target network; "ppo": a
    # policy (the network's outputs are its logits) and a value network over rollouts
    algo: str = "dqn"
    seed: int = 0
    num_seeds: int = 1
    total_timesteps: int = 240_000
    num_envs: int = 16
    # devices to shard over (``jaxnav.sharding``): seeds first, then each seed's envs
    devices: int = 1
    # network and loss
    hidden_sizes: tuple[int, ...] = (512, 256, 128, 64)
    dueling: bool = True
    double: bool = True
    layer_norm: bool = False
    # with layer_norm: LayerNorm and ReLU as one op with a float32 gradient
    # (``agents.layer_norm``), Pallas kernels on GPUs, the same math in jnp on a CPU
    # (``Trainer.norm_impl``)
    fused_layer_norm: bool = False
    compute_dtype: str = "float32"  # of the hidden layers' matrix products
    # units of a GRU cell between the MLP and the heads (a recurrent network whose hidden
    # state is carried along each env's episode, zeros at its start); 0: none
    memory: int = 0
    # a shipped policy's name (``jaxnav.pretrained``) or an exported npz whose weights start
    # the run (fine-tuning; optimizer, exploration and replay start afresh); "": random ones
    init_from: str = ""
    loss: str = "huber"
    # replay
    buffer_size: int = 100_000
    batch_size: int = 128
    # env steps of random actions before the first update, rounded up to whole iterations and
    # to at least n_step of them (the buffer must hold an n-step transition): at 16,384 envs
    # the default waits one iteration
    learning_starts: int = 10_000
    # sampled transitions per env step (the replay ratio): updates_per_iteration = replay_ratio *
    # num_envs / batch_size gradient steps per vectorized env step, which must be whole; held
    # fixed, the learning per env step (and target_update_period, in env steps) mean the same
    # at any num_envs. 8 = the paper's grid setting, 16 envs x 1 update of batch 128.
    replay_ratio: float = 8.0
    n_step: int = 1
    target_update_period: int = 2_000  # static, so skipped iterations cost nothing
    # PQN and PPO: each iteration steps every env rollout_length times, then num_epochs passes of
    # num_minibatches gradient steps over those num_envs * rollout_length transitions
    rollout_length: int = 1
    num_epochs: int = 1
    num_minibatches: int = 1
    optimizer: str = "adam"
    # per-run hyperparameters (vmappable leaves of HParams)
    gamma: float = 0.9
    lr: float = 1e-3
    lr_end: float = 1e-4
    max_grad_norm: float = 10.0
    tau: float = 1.0
    eps_start: float = 1.0
    eps_end: float = 0.05
    eps_decay_steps: int = 100_000
    td_lambda: float = 0.65  # PQN's lambda-returns, PPO's GAE (the same lambda)
    # PPO: the ratio's clip range (and the value's, with clip_value), the value loss's and
    # the policy entropy bonus's weights
    clip_eps: float = 0.2
    vf_coef: float = 0.5
    ent_coef: float = 0.01
    clip_value: bool = True
    # bookkeeping
    log_interval: int = 16_000
    eval_episodes: int = 1000

    @classmethod
    def for_env(cls, env: str = "GridMaze-v0", **overrides: Any) -> TrainConfig:
        """The config for ``env`` with the tuned defaults of that env and algorithm
        (``jaxnav.presets``; e.g. the robot envs train longer with 3-step returns), then
        ``overrides``; without an ``algo`` the env's default algorithm (``presets.default_algo``:
        the DQN, PQN on GridMaze-Random-v0)."""
        algo = overrides.get("algo", default_algo(env))
        return cls(env=env, **{"algo": algo, **train_defaults(env, algo), **overrides})

    @property
    def steps_per_iteration(self) -> int:
        """Env steps of one iteration: every env steps ``rollout_length`` times."""
        return self.num_envs * self.rollout_length

    @property
    def iterations(self) -> int:
        return self.num_logs * self.iterations_per_log

    @property
    def iterations_per_log(self) -> int:
        return max(1, self.log_interval // self.steps_per_iteration)

    @property
    def steps_per_log(self) -> int:
        return self.iterations_per_log * self.steps_per_iteration

    @property
    def num_logs(self) -> int:
        return max(1, math.ceil(self.total_timesteps / self.steps_per_log))

    def whole_intervals(self) -> tuple[TrainConfig, str]:
        """``(config, note)``: this config with ``total_timesteps`` rounded up to the steps a run
        trains, a whole number of logging intervals (a run is one scan over intervals of
        ``iterations_per_log`` iterations of ``num_envs * rollout_length`` env steps), and a
        one-line note of the rounding naming the command lines' flag (empty when none)."""
        total, trained = self.total_timesteps, self.num_logs * self.steps_per_log
        if total == trained:
            return self, ""
        note = (
            f"--total-timesteps {total} rounded up to {trained} ({self.num_logs} logging "
            f"interval{'s' if self.num_logs > 1 else ''} of {self.steps_per_log} env steps)"
        )
        return dataclasses.replace(self, total_timesteps=trained), note

    @property
    def algorithm(self) -> type[Algorithm]:
        """The class of ``algo`` (``jaxnav.algos.ALGOS``); ``ValueError`` for another name."""
        if self.algo not in ALGORITHMS:
            raise ValueError(f"algo={self.algo!r}: must be one of {', '.join(ALGORITHMS)}")
        return ALGORITHMS[self.algo]

    @property
    def first_learning_iteration(self) -> int:
        """The first iteration that takes gradient steps (the DQN's reaches
        ``learning_starts`` env steps and is at least the ``n_step``-th, when replay holds an
        n-step transition; PQN learns from its first rollout)."""
        return self.algorithm.first_learning_iteration(self)

    @property
    def learning_start_steps(self) -> int:
        """Env steps before the first update (``first_learning_iteration``'s)."""
        return self.first_learning_iteration * self.steps_per_iteration

    @property
    def updates_per_iteration(self) -> int:
        """Replay: gradient steps per vectorized env step, ``replay_ratio * num_envs /
        batch_size``; ``ValueError`` (one line) where that is not a whole number >= 1."""
        u = self.replay_ratio * self.num_envs / self.batch_size
        whole = round(u)
        if whole >= 1 and abs(u - whole) <= 1e-9 * whole:
            return whole
        raise ValueError(self._replay_ratio_error(u))

    def _replay_ratio_error(self, u: float) -> str:
        """The message for a replay ratio giving ``u`` gradient steps per iteration, not whole
        or below 1, with a batch size (else a replay ratio) that works."""
        r, n, b = self.replay_ratio, self.num_envs, self.batch_size
        head = (
            f"replay_ratio={r!r} with num_envs={n} and batch_size={b} gives "
            f"replay_ratio * num_envs / batch_size = {u:.6g} gradient steps per iteration, "
            "not a whole number >= 1"
        )
        sampled = r * n  # transitions sampled per iteration: a batch size must divide it
        shards = mesh_shape(self.num_seeds, self.devices)[1] if self.devices > 0 else 1
        fits = []
        # (a search of the divisors of at most 2**40 sampled transitions: a million candidates)
        if 1 <= sampled <= 2**40 and abs(sampled - round(sampled)) <= 1e-9 * sampled:
            total = round(sampled)
            fits = [
                d
                for d in _divisors(total)
                if d % shards == 0 and d <= self.buffer_size and total // d <= MAX_UPDATES
            ]
        if fits:
            best = min(fits, key=lambda d: (abs(math.log(d / b)), -d))
            return f"{head}; e.g. batch_size={best} ({round(sampled) // best} per iteration)"
        k = max(1, round(u))
        return (
            f"{head}; no batch size divides replay_ratio * num_envs = {sampled:.6g}: e.g. "
            f"replay_ratio={k * b / n} ({k} per iteration)"
        )

    @property
    def updates_per_learning_iteration(self) -> int:
        """Gradient steps of an iteration that learns."""
        return self.algorithm.updates_per_learning_iteration(self)

    @property
    def minibatch_size(self) -> int:
        """Transitions per gradient step."""
        return self.algorithm.minibatch_size(self)

    @property
    def buffer_rows(self) -> int:
        return max(self.n_step, self.buffer_size // self.num_envs)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad value or combination."""
        env_config(self.env, **self.env_kwargs)
        ints = {
            "seed": (0, 2**31 - 1),
            "num_seeds": (1, 4096),
            "total_timesteps": (1, MAX_STEPS),
            "num_envs": (1, 2**24),
            "devices": (1, 65536),
            "buffer_size": (1, 10**9),
            "batch_size": (1, 2**20),
            "learning_starts": (0, MAX_STEPS),
            "n_step": (1, 64),
            "rollout_length": (1, 4096),
            "num_epochs": (1, 1024),
            "num_minibatches": (1, 2**20),
            "target_update_period": (1, MAX_STEPS),
            "eps_decay_steps": (1, MAX_STEPS),
            "log_interval": (1, MAX_STEPS),
            "eval_episodes": (0, 10**7),
            "memory": (0, 65536),
        }
        for name, (lo, hi) in ints.items():
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
                raise ValueError(f"{name}={v!r}: must be an integer in [{lo}, {hi}]")
        floats = {
            "gamma": (0.0, 1.0),
            "lr": (0.0, 10.0),
            "lr_end": (0.0, 10.0),
            "max_grad_norm": (0.0, 1e9),
            "tau": (0.0, 1.0),
            "eps_start": (0.0, 1.0),
            "eps_end": (0.0, 1.0),
            "td_lambda": (0.0, 1.0),
            "clip_eps": (0.0, 1.0),
            "vf_coef": (0.0, 1e3),
            "ent_coef": (0.0, 1e3),
            "replay_ratio": (0.0, float(MAX_UPDATES * 2**20)),
        }
        for name, (lo, hi) in floats.items():
            v = getattr(self, name)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not ok or not lo <= v <= hi:
                raise ValueError(f"{name}={v!r}: must be a number in [{lo}, {hi}]")
        positive = ("lr", "max_grad_norm", "tau", "replay_ratio", "clip_eps")
        bad = next((n for n in positive if getattr(self, n) <= 0), None)
        if bad is not None:
            raise ValueError(f"{bad}={getattr(self, bad)!r}: must be positive")
        if not self.hidden_sizes or any(
            not isinstance(h, int) or isinstance(h, bool) or not 1 <= h <= 65536
            for h in self.hidden_sizes
        ):
            raise ValueError(
                f"hidden_sizes={self.hidden_sizes!r}: must be one or more integers in [1, 65536]"
            )
        for name in ("dueling", "double", "layer_norm", "fused_layer_norm", "clip_value"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name}={getattr(self, name)!r}: must be true or false")
        for name, choices in (("algo", ALGOS), ("compute_dtype", COMPUTE_DTYPES)):
            if getattr(self, name) not in choices:
                raise ValueError(
                    f"{name}={getattr(self, name)!r}: must be one of {', '.join(choices)}"
                )
        if self.loss not in ("huber", "mse"):
            raise ValueError(f"loss={self.loss!r}: must be one of huber, mse")
        if self.optimizer not in ("adam", "sgd"):
            raise ValueError(f"optimizer={self.optimizer!r}: must be one of adam, sgd")
        if not isinstance(self.init_from, str):
            raise ValueError(
                f"init_from={self.init_from!r}: must be a shipped policy's name or an npz file"
            )
        if self.devices > jax.device_count():
            raise ValueError(
                f"devices={self.devices}: only {jax.device_count()} device(s) are available"
            )
        env_shards = mesh_shape(self.num_seeds, self.devices)[1]
        for name in ("num_envs", "minibatch_size"):
            if getattr(self, name) % env_shards:
                shown = self.algorithm.minibatch_field if name == "minibatch_size" else name
                raise ValueError(
                    f"{shown}={getattr(self, name)} is not a multiple of the {env_shards} "
                    f"devices each seed's envs are split over (devices={self.devices}, "
                    f"num_seeds={self.num_seeds})"
                )
        if self.iterations * self.steps_per_iteration > MAX_STEPS:
            raise ValueError(
                f"total_timesteps={self.total_timesteps}: rounded up to whole logging intervals "
                f"it exceeds {MAX_STEPS} steps"
            )
        if self.memory and not self.algorithm.recurrent:
            recurrent = ", ".join(n for n, a in ALGORITHMS.items() if a.recurrent)
            raise ValueError(
                f"memory={self.memory}: algo={self.algo} has no recurrent network; "
                f"memory is for algo {recurrent}"
            )
        self.algorithm.validate(self)


def _divisors(n: int) -> list[int]:
    small = [d for d in range(1, math.isqrt(n) + 1) if n % d == 0]
    return sorted(set(small + [n // d for d in small]))


def upgrade_saved(d: dict[str, Any]) -> dict[str, Any]:
    """A saved ``TrainConfig`` dict (a run's config.json, ``dataclasses.asdict``) in today's
    fields: one written before ``replay_ratio`` has ``updates_per_iteration`` u instead, the
    same training as ``replay_ratio = u * batch_size / num_envs``."""
    d = dict(d)
    if "updates_per_iteration" in d:
        u = d.pop("updates_per_iteration")
        if "replay_ratio" not in d:
            batch = d.get("batch_size", TrainConfig.batch_size)
            envs = d.get("num_envs", TrainConfig.num_envs)
            # (an edited num_envs of 0: left to validate() to name)
            d["replay_ratio"] = u * batch / envs if envs else u
    return d
