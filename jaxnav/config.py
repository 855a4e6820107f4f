"""Training configuration: one frozen dataclass, validated before anything compiles."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import jax

from jaxnav import pretrained
from jaxnav.agents.dqn import COMPUTE_DTYPES
from jaxnav.algos import ALGOS as ALGORITHMS
from jaxnav.algos.base import MAX_UPDATES, Algorithm
from jaxnav.presets import default_algo, train_defaults
from jaxnav.registration import env_config, registered_envs
from jaxnav.sharding import mesh_shape

# step counters are int32 inside the compiled loop; keep a margin below 2^31
MAX_STEPS = 2_000_000_000
ALGOS = tuple(ALGORITHMS)  # the names ``algo`` takes


# A setting's check: what is wrong with a value, as the end of a one-line error; None if fine
Check = Callable[[Any], str | None]


def setting(default: Any, help: str, check: Check | None = None, hparam: bool = False) -> Any:
    """A ``TrainConfig`` field, declared once: its default, its ``--help`` text, the ``check``
    ``validate`` runs on its value alone and whether it is a vmappable leaf of
    ``jaxnav.train.HParams`` (``hparam``); the training CLI's flag is its name."""
    return dataclasses.field(
        default=default, metadata={"help": help, "check": check, "hparam": hparam}
    )


def integer(lo: int, hi: int) -> Check:
    """An integer (not a bool) in [lo, hi]."""

    def check(v: Any) -> str | None:
        ok = isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi
        return None if ok else f"must be an integer in [{lo}, {hi}]"

    return check


def number(lo: float, hi: float, positive: bool = False) -> Check:
    """A finite number (not a bool) in [lo, hi], and above 0 where ``positive``."""

    def check(v: Any) -> str | None:
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if not ok or not lo <= v <= hi:
            return f"must be a number in [{lo}, {hi}]"
        return "must be positive" if positive and v <= 0 else None

    return check


def one_of(*choices: str) -> Check:
    """One of ``choices``."""
    return lambda v: None if v in choices else f"must be one of {', '.join(choices)}"


def boolean(v: Any) -> str | None:
    """True or False, not a number or a string."""
    return None if isinstance(v, bool) else "must be true or false"


def widths(v: Any) -> str | None:
    """One or more layer widths, integers in [1, 65536]."""
    ok = bool(v) and all(integer(1, 65536)(h) is None for h in v)
    return None if ok else "must be one or more integers in [1, 65536]"


def policy_source(v: Any) -> str | None:
    """Empty, a shipped policy's name or an npz file's path (read when a run starts)."""
    if isinstance(v, str) and (not v or v.endswith(".npz")):
        return None  # the common case reads no manifest
    shipped = pretrained.names()
    if isinstance(v, str) and v in shipped:
        return None
    return f"must be a shipped policy ({', '.join(shipped)}) or an npz file"


def _algo_help() -> str:
    """``algo``'s help: "dqn (its summary), pqn (...) or ppo (...)", from the registry."""
    named = [f"{name} ({algorithm.summary})" for name, algorithm in ALGORITHMS.items()]
    return f"{', '.join(named[:-1])} or {named[-1]}"


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Defaults reproduce the paper's grid experiment (Sec. IV-A) on a laptop CPU.

    Sizes count env steps (transitions of one env) unless named otherwise. Each field is a
    ``setting``: validation, ``HParams`` and the training CLI's flags are read off it.
    """

    env: str = setting("GridMaze-v0", f"environment id ({', '.join(registered_envs())})")
    # the env's own config fields (validated by it), set by the CLI's --env-arg KEY=VALUE
    env_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    algo: str = setting("dqn", _algo_help(), one_of(*ALGOS))
    seed: int = setting(0, "first seed; seeds are seed .. seed+num_seeds-1", integer(0, 2**31 - 1))
    num_seeds: int = setting(1, "seeds trained at once (vmapped in one program)", integer(1, 4096))
    total_timesteps: int = setting(240_000, "env steps per seed", integer(1, MAX_STEPS))
    num_envs: int = setting(16, "parallel environments per seed", integer(1, 2**24))
    devices: int = setting(
        1,
        "devices to shard over, a count or 'all' (of every host): seeds are split first, then "
        "each seed's envs, with gradients averaged across its devices",
        integer(1, 65536),
    )
    # network and loss
    hidden_sizes: tuple[int, ...] = setting(
        (512, 256, 128, 64), "MLP widths, comma separated (the paper's: 512,256,128,64)", widths
    )
    dueling: bool = setting(True, "dueling heads V + A - mean(A) (paper eq. 7)", boolean)
    double: bool = setting(True, "double-DQN targets (paper eq. 6)", boolean)
    layer_norm: bool = setting(False, "LayerNorm before each hidden ReLU (PQN's network)", boolean)
    # Trainer.norm_impl picks the kernels (agents.layer_norm)
    fused_layer_norm: bool = setting(
        False,
        "LayerNorm and ReLU as one op with a float32 gradient: Pallas kernels on a GPU (on each "
        "device's rows over several), jnp on a CPU",
        boolean,
    )
    compute_dtype: str = setting(
        "float32",
        "float32 or bfloat16 matrix products in the hidden layers",
        one_of(*COMPUTE_DTYPES),
    )
    memory: int = setting(
        0,
        "units of a GRU cell between the MLP and the heads, its hidden state carried through "
        "each episode and reset at its start (0: no memory); pqn and ppo",
        integer(0, 65536),
    )
    init_from: str = setting(
        "",
        "start from the weights of a shipped policy (python -m jaxnav.pretrained lists them) or "
        "an exported npz, to fine-tune it: its network and observation must be the run's; "
        "optimizer, exploration and replay start afresh",
        policy_source,
    )
    loss: str = setting("huber", "huber or mse", one_of("huber", "mse"))
    # replay
    buffer_size: int = setting(100_000, "replay capacity in transitions", integer(1, 10**9))
    batch_size: int = setting(128, "transitions per gradient step", integer(1, 2**20))
    # at least n_step iterations: the buffer must hold an n-step transition; at 16,384 envs
    # the default waits one iteration
    learning_starts: int = setting(
        10_000,
        "env steps of random actions before the first update (whole iterations, at least "
        "n_step of them)",
        integer(0, MAX_STEPS),
    )
    # held fixed, the learning per env step (and target_update_period, in env steps) mean the
    # same at any num_envs; 8 = the paper's grid setting, 16 envs x 1 update of batch 128
    replay_ratio: float = setting(
        8.0,
        "dqn: sampled transitions per env step; an iteration (one step of every env) takes "
        "replay_ratio * num_envs / batch_size gradient steps, a whole number",
        number(0.0, float(MAX_UPDATES * 2**20), positive=True),
    )
    n_step: int = setting(1, "n-step returns", integer(1, 64))
    # static, so skipped iterations cost nothing
    target_update_period: int = setting(
        2_000, "env steps between target-network updates", integer(1, MAX_STEPS)
    )
    rollout_length: int = setting(
        1, "pqn, ppo: env steps of every env per iteration", integer(1, 4096)
    )
    num_epochs: int = setting(1, "pqn, ppo: passes over each rollout", integer(1, 1024))
    num_minibatches: int = setting(
        1, "pqn, ppo: gradient steps per pass over a rollout", integer(1, 2**20)
    )
    optimizer: str = setting("adam", "adam or sgd", one_of("adam", "sgd"))
    gamma: float = setting(0.9, "discount", number(0.0, 1.0), hparam=True)
    lr: float = setting(
        1e-3, "learning rate at the start", number(0.0, 10.0, positive=True), hparam=True
    )
    lr_end: float = setting(
        1e-4, "learning rate at the end (linear decay)", number(0.0, 10.0), hparam=True
    )
    max_grad_norm: float = setting(
        10.0, "global-norm gradient clipping", number(0.0, 1e9, positive=True), hparam=True
    )
    tau: float = setting(
        1.0, "target update weight (1 = hard copy)", number(0.0, 1.0, positive=True), hparam=True
    )
    eps_start: float = setting(
        1.0, "exploration epsilon at the start", number(0.0, 1.0), hparam=True
    )
    eps_end: float = setting(
        0.05, "exploration epsilon after eps_decay_steps", number(0.0, 1.0), hparam=True
    )
    eps_decay_steps: int = setting(
        100_000, "env steps of linear epsilon decay", integer(1, MAX_STEPS), hparam=True
    )
    td_lambda: float = setting(
        0.65, "pqn: lambda of the lambda-returns; ppo: of GAE", number(0.0, 1.0), hparam=True
    )
    clip_eps: float = setting(
        0.2,
        "ppo: clip range of the probability ratio (and of the value, with clip_value)",
        number(0.0, 1.0, positive=True),
    )
    vf_coef: float = setting(0.5, "ppo: weight of the value loss", number(0.0, 1e3))
    ent_coef: float = setting(0.01, "ppo: weight of the policy's entropy bonus", number(0.0, 1e3))
    clip_value: bool = setting(
        True, "ppo: clip the value's change from the rollout's as the ratio is clipped", boolean
    )
    curriculum: str = setting(
        "none",
        "how fresh episodes draw their layout from the env's bank: none (uniformly) or "
        "learnability (SFL's levels the policy solves sometimes: by p(1-p) of each layout's "
        "recent success p, mixed with uniform draws; jaxnav.train.curriculum)",
        one_of("none", "learnability"),
    )
    # bookkeeping
    log_interval: int = setting(
        16_000, "env steps per metrics row and progress line", integer(1, MAX_STEPS)
    )
    eval_episodes: int = setting(1000, "greedy evaluation episodes at the end", integer(0, 10**7))

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
        """Raise ``ValueError`` naming the first bad setting (in declaration order, by its
        ``check``), else the first bad combination."""
        env_config(self.env, **self.env_kwargs)
        for f in dataclasses.fields(self):
            check, value = f.metadata.get("check"), getattr(self, f.name)
            fault = check(value) if check else None
            if fault:
                raise ValueError(f"{f.name}={value!r}: {fault}")
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


# the settings marked hparam, in declaration order: the fields of jaxnav.train.HParams
HPARAMS = tuple(f.name for f in dataclasses.fields(TrainConfig) if f.metadata.get("hparam"))


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
