"""Functional Q-learning pieces: Q-network (``dueling``, ``layer_norm`` and ``memory``
flags), the TD regression loss, DQN targets (``double`` flag) and the replay buffer.

With ``dueling=False`` and ``double=False`` this is the paper's "simple DQN"; with both on it is
the paper's model (eq. 6 and 7 of the paper). PQN (``jaxnav.agents.pqn``) uses the same network
(with ``layer_norm``) and loss, with lambda-returns for targets instead of a target network.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.sharding import Mesh

from jaxnav import backend
from jaxnav.agents.layer_norm import layer_norm_relu
from jaxnav.deploy.policy import GRU_GATES


def expand_onehot(obs: jax.Array, onehot_sizes: Sequence[int]) -> jax.Array:
    """float32 ``obs`` with value i one-hot encoded into ``onehot_sizes[i]`` columns (kept as
    one number where that is 0)."""
    parts = [
        jax.nn.one_hot(obs[..., i].astype(jnp.int32), n)
        if n
        else obs[..., i : i + 1].astype(jnp.float32)
        for i, n in enumerate(onehot_sizes)
    ]
    return jnp.concatenate(parts, axis=-1)


def input_size(obs_size: int, onehot_sizes: Sequence[int] | None) -> int:
    """Width of the first layer's input for observations of ``obs_size`` values."""
    return obs_size if onehot_sizes is None else sum(n or 1 for n in onehot_sizes)


InputSpec = tuple[int, tuple[int, ...] | None]  # (obs_size, onehot_sizes): what a network reads


def check_input_fits(env_id: str, have: InputSpec, want: InputSpec) -> None:
    """``ValueError`` if ``env_id``'s observations (``have``) are not what a trained network
    reads (``want``), e.g. "(10,) one-hot encoded to 30" for "(10,) one-hot encoded to 34"."""
    if have == want:
        return

    def describe(obs_size: int, onehot_sizes: tuple[int, ...] | None) -> str:
        if onehot_sizes is None:
            return f"({obs_size},)"
        return f"({obs_size},) one-hot encoded to {input_size(obs_size, onehot_sizes)}"

    raise ValueError(
        f"--env {env_id}: observations {describe(*have)} do not fit the run's network "
        f"{describe(*want)}"
    )


def flax_params(arrays: dict[str, Any], network: dict[str, Any]) -> dict[str, Any]:
    """The inverse of ``jaxnav.export.policy_arrays``: ``QNetwork`` parameters from exported
    arrays and the metadata's ``network`` (to evaluate, render or fine-tune an exported policy
    with JAX)."""
    p: dict[str, Any] = {}
    n = len(network["hidden_sizes"])
    for i in range(n):
        p[f"Dense_{i}"] = {"kernel": arrays[f"dense{i}_kernel"], "bias": arrays[f"dense{i}_bias"]}
        if network["layer_norm"]:
            scale, bias = arrays[f"norm{i}_scale"], arrays[f"norm{i}_bias"]
            p[f"LayerNorm_{i}"] = {"scale": scale, "bias": bias}
    if network.get("memory"):
        p["memory"] = {
            gate: {"kernel": arrays[f"gru_{gate}_kernel"]}
            | ({"bias": arrays[f"gru_{gate}_bias"]} if biased else {})
            for gate, biased in GRU_GATES.items()
        }
    if network["dueling"]:
        for head in ("value", "advantage"):
            p[head] = {"kernel": arrays[f"{head}_kernel"], "bias": arrays[f"{head}_bias"]}
    else:
        p[f"Dense_{n}"] = {"kernel": arrays["head_kernel"], "bias": arrays["head_bias"]}
    return {"params": jax.tree.map(jnp.asarray, p)}


COMPUTE_DTYPES = ("float32", "bfloat16")
NORM_IMPLS = ("flax", "fused", "pallas")  # QNetwork.norm_impl
# the paper's two agents (Sec. IV) as QNetwork / loss flags, and how tables and figures name
# them and the random agent
PAPER_AGENTS = {
    "dueling-double": {"dueling": True, "double": True},
    "simple": {"dueling": False, "double": False},
}
AGENT_LABELS = {
    "dueling-double": "dueling double DQN",
    "simple": "simple DQN",
    "random": "random agent",
}


class DenseParams(nn.Module):
    """``nn.Dense``'s parameters (initializers, names, dtype) without its product."""

    features: int

    @nn.compact
    def __call__(self, in_features: int) -> tuple[jax.Array, jax.Array]:
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (in_features, self.features))
        return kernel, self.param("bias", nn.initializers.zeros_init(), (self.features,))


class LayerNormParams(nn.Module):
    """``nn.LayerNorm``'s parameters (scale, then bias) without its normalization."""

    @nn.compact
    def __call__(self, features: int) -> tuple[jax.Array, jax.Array]:
        scale = self.param("scale", nn.initializers.ones_init(), (features,))
        return scale, self.param("bias", nn.initializers.zeros_init(), (features,))


class QNetwork(nn.Module):
    """MLP Q-network; the paper's is 512-256-128-64 with dueling heads.

    ``onehot_sizes`` (an env's ``obs_onehot_sizes``) one-hot encodes compact observations
    first; one-hot times a dense layer is an embedding lookup, the same function.
    ``layer_norm`` normalizes each hidden layer before its ReLU (PQN's network: it keeps
    bootstrapped targets from diverging without a target network). ``compute_dtype``
    "bfloat16" runs the matrix products in bfloat16 (parameters and Q-values stay float32).
    ``norm_impl`` computes LayerNorm and ReLU: "flax" (``nn.LayerNorm``, ``nn.relu``), or as
    one op with a float32 gradient (``agents.layer_norm``) in jnp ("fused") or as Pallas
    kernels ("pallas"); all three have the same parameters, initialized alike.

    ``memory`` > 0 puts a GRU cell (``nn.GRUCell``, named "memory") of that many units between
    the MLP and the heads: the network is then called with its hidden state ``[N, memory]``
    (zeros at an episode's start, ``initial_memory``) and returns ``(outputs, hidden state
    after the step)``; ``unroll`` runs it over sequences."""

    num_actions: int
    hidden_sizes: Sequence[int] = (512, 256, 128, 64)
    dueling: bool = True
    onehot_sizes: tuple[int, ...] | None = None
    layer_norm: bool = False
    compute_dtype: str = "float32"
    norm_impl: str = "flax"
    mesh: Mesh | None = None  # "pallas" over several devices: each device's rows
    rows_axis: str | None = None  # the mesh axis the rows (envs, batch) are split over
    memory: int = 0  # units of the GRU cell after the MLP; 0: none (a feed-forward network)

    def initial_memory(self, n: int) -> jax.Array | None:
        """The hidden state of ``n`` episodes' starts (zeros), None without ``memory``."""
        return jnp.zeros((n, self.memory), jnp.float32) if self.memory else None

    def compute_params(self, params: Any) -> Any:
        """``params`` with the hidden layers' weight matrices in ``compute_dtype``, which the
        network casts them to on every call anyway: applying it to these gives the same
        values, with the cast done once for many calls (a rollout's acting passes)."""
        hidden = {f"Dense_{i}" for i in range(len(self.hidden_sizes))}
        dtype = jnp.dtype(self.compute_dtype)

        def cast(path: tuple, leaf: jax.Array) -> jax.Array:
            names = [getattr(k, "key", None) for k in path]
            return leaf.astype(dtype) if names[-1] == "kernel" and hidden & set(names) else leaf

        return jax.tree_util.tree_map_with_path(cast, params)

    @nn.compact
    def __call__(
        self, obs: jax.Array, hidden: jax.Array | None = None, done: jax.Array | None = None
    ) -> Any:
        """Outputs of ``obs`` [..., D]; with ``memory``, ``(outputs, hidden state after the
        step)`` from ``hidden`` [..., memory], or, given ``done`` [T, N], of whole sequences
        ``obs`` [T, N, D] from ``hidden`` [N, memory], the state reset after the steps where
        ``done`` (``unroll``)."""
        sequences = done is not None
        if sequences:  # the MLP over every step at once; only the GRU cell steps through time
            time_env = obs.shape[:2]
            obs = obs.reshape(-1, obs.shape[-1])
        if self.onehot_sizes is None:
            x = obs.astype(jnp.float32)  # observations may be stored compactly (int8)
        else:
            x = expand_onehot(obs, self.onehot_sizes)
        if self.norm_impl not in NORM_IMPLS:
            raise ValueError(
                f"norm_impl={self.norm_impl!r}: must be one of {', '.join(NORM_IMPLS)}"
            )
        dtype = jnp.dtype(self.compute_dtype)
        fused = self.layer_norm and self.norm_impl != "flax"
        for i, width in enumerate(self.hidden_sizes):
            if fused:
                # the names flax gives nn.Dense and nn.LayerNorm: the same parameter tree
                kernel, dense_bias = DenseParams(width, name=f"Dense_{i}")(x.shape[-1])
                scale, bias = LayerNormParams(name=f"LayerNorm_{i}")(width)
                z = jnp.dot(x.astype(dtype), kernel.astype(dtype))
                pallas = self.norm_impl == "pallas"
                x = layer_norm_relu(z, dense_bias, scale, bias, pallas, self.mesh, self.rows_axis)
                continue
            x = nn.Dense(width, dtype=dtype)(x)
            if self.layer_norm:
                x = nn.LayerNorm(dtype=dtype)(x)
            x = nn.relu(x)
        x = x.astype(jnp.float32)  # the heads in float32: Q-values are compared and regressed
        if not self.memory:
            return self.heads(x)
        cell = nn.GRUCell(self.memory, name="memory")
        if not sequences:
            if hidden is None:  # (``init``) an episode's start
                hidden = jnp.zeros((*x.shape[:-1], self.memory), jnp.float32)
            hidden, x = cell(hidden, x)
            return self.heads(x), hidden

        def step(cell: nn.GRUCell, h: jax.Array, xs: tuple) -> tuple[jax.Array, tuple]:
            x_t, done_t = xs
            after, y = cell(h, x_t)
            return reset_memory(after, done_t), (y, after)

        scan = nn.scan(step, variable_broadcast="params", split_rngs={"params": False})
        _, (x, after) = scan(cell, hidden, (x.reshape(*time_env, -1), done))
        return self.heads(x), after

    def heads(self, x: jax.Array) -> jax.Array:
        """The outputs of the last hidden features ``x``: one dense layer, or the dueling
        heads."""
        if not self.dueling:
            return nn.Dense(self.num_actions, name=f"Dense_{len(self.hidden_sizes)}")(x)
        # eq. 7, Q = V + (A - mean_a A), which makes V and A identifiable, is linear in x: one
        # product with the combined weights, where two products and a mean ran as many small
        # kernels forward and backward (the same function; the same parameters as two nn.Dense)
        value_kernel, value_bias = DenseParams(1, name="value")(x.shape[-1])
        kernel, bias = DenseParams(self.num_actions, name="advantage")(x.shape[-1])
        # the mean over actions as a sum of columns: elementwise, so XLA fuses it with the
        # rest (a mean over the last axis ran as a kernel of its own)
        columns = range(self.num_actions)
        kernel_mean = sum(kernel[:, a : a + 1] for a in columns) / self.num_actions
        bias_mean = sum(bias[a] for a in columns) / self.num_actions
        return jnp.dot(x, value_kernel + kernel - kernel_mean) + (value_bias + bias - bias_mean)


@dataclasses.dataclass(frozen=True)
class RecurrentPolicy:
    """A policy that keeps a state through each episode (a recurrent network's hidden state):
    ``start(n)`` is the state of ``n`` episodes' starts, ``step(state, key, obs[N, D]) ->
    (state, action[N])`` acts and advances it (``jaxnav.evaluate.play`` carries it)."""

    start: Callable[[int], Any]
    step: Callable[[Any, jax.Array, jax.Array], tuple[Any, jax.Array]]


def reset_memory(hidden: jax.Array, done: jax.Array) -> jax.Array:
    """``hidden`` [N, H] with zeros (an episode's start) where ``done`` [N]: the next step of
    those envs is a new episode's first, which must not read the ended one's memory."""
    return jnp.where(done[:, None], jnp.zeros_like(hidden), hidden)


def unroll(
    apply_fn: Any, params: Any, obs: jax.Array, hidden: jax.Array, done: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """A recurrent network (``QNetwork`` with ``memory``) over sequences laid out [time, env]:
    ``(outputs [T, N, A], hidden states after each step [T, N, H])`` of observations ``obs``
    [T, N, D] from ``hidden`` [N, H], the state reset (``reset_memory``) after the steps where
    ``done`` [T, N]."""

    return apply_fn(params, obs, hidden, done)


def sequence_outputs(
    apply_fn: Any, params: Any, obs: jax.Array, hidden: jax.Array, done: jax.Array
) -> jax.Array:
    """``unroll`` over a minibatch of sequences laid out [env, time] (``obs`` [B, T, D],
    ``hidden`` [B, H] their state at the start, ``done`` [B, T]): the outputs as rows
    [B * T, A] in that order, env by env."""
    swap = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731
    out = unroll(apply_fn, params, swap(obs), hidden, swap(done))[0]
    return swap(out).reshape(-1, out.shape[-1])


# ---------------------------------------------------------------------------- replay
@struct.dataclass
class ReplayBuffer:
    """Circular buffer laid out [time, env], so n-step returns read consecutive rows.

    ``next_obs`` holds the observation after the transition; at an episode end it is the
    final observation (not the reset one), so truncated transitions bootstrap correctly.
    """

    obs: jax.Array  # [T, N, D]
    action: jax.Array  # [T, N]
    reward: jax.Array  # [T, N]
    next_obs: jax.Array  # [T, N, D]
    terminated: jax.Array  # [T, N] bool: no bootstrap
    done: jax.Array  # [T, N] bool: episode ended (terminated or truncated)
    ptr: jax.Array  # next row to write
    size: jax.Array  # rows filled

    @property
    def capacity(self) -> int:
        return self.obs.shape[0]


def buffer_init(
    capacity: int, num_envs: int, obs_size: int, obs_dtype: Any = jnp.float32
) -> ReplayBuffer:
    f = lambda *s, d=jnp.float32: jnp.zeros((capacity, num_envs, *s), d)  # noqa: E731
    return ReplayBuffer(
        obs=f(obs_size, d=obs_dtype),
        action=f(d=jnp.int32),
        reward=f(),
        next_obs=f(obs_size, d=obs_dtype),
        terminated=f(d=bool),
        done=f(d=bool),
        ptr=jnp.zeros((), jnp.int32),
        size=jnp.zeros((), jnp.int32),
    )


def buffer_add(
    buf: ReplayBuffer,
    obs: jax.Array,
    action: jax.Array,
    reward: jax.Array,
    next_obs: jax.Array,
    terminated: jax.Array,
    done: jax.Array,
) -> ReplayBuffer:
    """Write one row (one transition of every env) at ``ptr``, overwriting the oldest."""
    i = buf.ptr
    return buf.replace(
        obs=buf.obs.at[i].set(obs),
        action=buf.action.at[i].set(action),
        reward=buf.reward.at[i].set(reward),
        next_obs=buf.next_obs.at[i].set(next_obs),
        terminated=buf.terminated.at[i].set(terminated),
        done=buf.done.at[i].set(done),
        ptr=(i + 1) % buf.capacity,
        size=jnp.minimum(buf.size + 1, buf.capacity),
    )


@struct.dataclass
class Batch:
    obs: jax.Array
    action: jax.Array
    returns: jax.Array  # n-step discounted reward sum
    bootstrap_obs: jax.Array
    bootstrap_discount: jax.Array  # gamma^k, 0 after a terminal state


def buffer_sample(
    buf: ReplayBuffer, key: jax.Array, batch_size: int, n_step: int, gamma: jax.Array
) -> Batch:
    """Uniform sample of n-step transitions that do not straddle the write pointer.

    Requires ``buf.size >= n_step``.
    """
    k_t, k_e = jax.random.split(key)
    oldest = (buf.ptr - buf.size) % buf.capacity
    j = jax.random.randint(k_t, (batch_size,), 0, buf.size - n_step + 1)
    t = (oldest + j) % buf.capacity
    e = jax.random.randint(k_e, (batch_size,), 0, buf.obs.shape[1])
    returns = jnp.zeros(batch_size)
    discount = jnp.ones(batch_size)
    alive = jnp.ones(batch_size, bool)
    last = t
    boot = jnp.zeros(batch_size)
    for k in range(n_step):  # n_step is small and static
        idx = (t + k) % buf.capacity
        returns = returns + jnp.where(alive, discount * buf.reward[idx, e], 0.0)
        discount = discount * gamma
        last = jnp.where(alive, idx, last)
        boot = jnp.where(alive, discount * (1.0 - buf.terminated[idx, e]), boot)
        alive = alive & ~buf.done[idx, e]
    return Batch(
        obs=buf.obs[t, e],
        action=buf.action[t, e],
        returns=returns,
        bootstrap_obs=buf.next_obs[last, e],
        bootstrap_discount=boot,
    )


# ---------------------------------------------------------------------------- loss
def taken_values(q: jax.Array, action: jax.Array, masked: bool) -> jax.Array:
    """``q[i, action[i]]``: with ``masked``, as a sum over the actions of ``q`` where the
    action was taken, whose gradient is elementwise (on a GPU ``take_along_axis``'s gradient
    is a scatter-add into zeros, two more kernels a gradient step); without, by
    ``take_along_axis`` (on a CPU the masked sum made the grid's DQN a few percent slower)."""
    if masked:
        return jnp.where(action[:, None] == jnp.arange(q.shape[-1]), q, 0.0).sum(axis=-1)
    return jnp.take_along_axis(q, action[:, None], axis=-1)[:, 0]


def regression_loss(
    params, apply_fn, obs: jax.Array, action: jax.Array, target: jax.Array, loss_type: str
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Mean TD loss of ``Q(obs, action)`` against fixed ``target`` values, and its diagnostics
    per row (``DIAGNOSTICS``: summed over a loop's gradient steps with ``diagnostics_add``,
    reduced once after it with ``diagnostics_means``); ``loss_type`` "huber" (delta 1) or
    "mse" (the squared error)."""
    q = apply_fn(params, obs)
    q_taken = taken_values(q, action, masked=backend.masked_taken_values())
    td = q_taken - jax.lax.stop_gradient(target)
    if loss_type == "huber":
        per_sample = jnp.where(jnp.abs(td) <= 1.0, 0.5 * td**2, jnp.abs(td) - 0.5)
    else:
        per_sample = td**2
    rows = {"loss": per_sample, "q_mean": q_taken, "q_max": jnp.abs(q).max(axis=-1)}
    return per_sample.mean(), rows


# What ``regression_loss`` reports of a gradient step, per row: the TD loss, the taken
# action's Q-value and the largest |Q|. A loop of gradient steps keeps their running sums (max
# for q_max), each row apart: on a GPU a reduction to a scalar is a kernel, and three a step
# were 5 of the DQN's 70 kernels a gradient step; sums per row fuse into the kernels that
# compute the rows (measured: docs/performance.md).
DIAGNOSTICS = ("loss", "q_mean", "q_max")


def diagnostics_init(rows: int) -> dict[str, jax.Array]:
    """Running sums for ``diagnostics_add`` over steps of ``rows`` rows."""
    return {name: jnp.zeros(rows) for name in DIAGNOSTICS}


def diagnostics_add(total: dict[str, jax.Array], rows: dict[str, jax.Array]) -> dict:
    """``total`` with one gradient step's per-row diagnostics added (q_max: the larger)."""
    return {
        "loss": total["loss"] + rows["loss"],
        "q_mean": total["q_mean"] + rows["q_mean"],
        "q_max": jnp.maximum(total["q_max"], rows["q_max"]),  # NaN stays NaN
    }


def diagnostics_means(total: dict[str, jax.Array], steps: int) -> dict[str, jax.Array]:
    """The mean loss and Q-value over ``steps`` gradient steps summed in ``total``, and the
    largest |Q| any of them saw."""
    return {
        "loss": total["loss"].mean() / steps,
        "q_mean": total["q_mean"].mean() / steps,
        "q_max": total["q_max"].max(),
    }


def dqn_target(params, target_params, apply_fn, batch: Batch, double: bool) -> jax.Array:
    """``returns + bootstrap_discount * Q_target(s', a*)`` with ``a* = argmax Q_target(s')``
    (simple DQN, eq. 5) or ``a* = argmax Q_online(s')`` (``double``, eq. 6)."""
    q_next_target = apply_fn(target_params, batch.bootstrap_obs)
    if double:
        # its own pass, gradient stopped: one pass over s and s' together would also run the
        # backward pass over the s' rows (zero cotangents, full cost: 1.7x the gradient time)
        q_next_online = apply_fn(jax.lax.stop_gradient(params), batch.bootstrap_obs)
        best = jnp.argmax(q_next_online, axis=-1)
    else:
        best = jnp.argmax(q_next_target, axis=-1)
    next_value = taken_values(q_next_target, best, masked=False)  # no gradient: no scatter
    return jax.lax.stop_gradient(batch.returns + batch.bootstrap_discount * next_value)


def td_loss(
    params,
    target_params,
    apply_fn,
    batch: Batch,
    double: bool,
    loss_type: str = "huber",
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """DQN's mean TD loss of a replay batch against ``dqn_target``, and diagnostics."""
    target = dqn_target(params, target_params, apply_fn, batch, double)
    return regression_loss(params, apply_fn, batch.obs, batch.action, target, loss_type)


def polyak(target_params: Any, params: Any, tau: jax.Array) -> Any:
    """``tau * params + (1 - tau) * target``; tau = 1 is a hard copy."""
    return optax.incremental_update(params, target_params, tau)
