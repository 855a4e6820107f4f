"""PQN's targets (Gallici et al. 2024, "Simplifying Deep Temporal Difference Learning"):
lambda-returns over a rollout of many parallel envs, bootstrapped from the online network.

PQN has no replay buffer and no target network: each iteration collects ``rollout_length``
steps of every env, computes these targets once with the current parameters, and regresses
the LayerNorm Q-network (``dqn.QNetwork(layer_norm=True)``) onto them for a few epochs of
minibatches (``jaxnav.algos.pqn``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def lambda_returns(
    reward: jax.Array,
    terminated: jax.Array,
    done: jax.Array,
    next_value: jax.Array,
    gamma: jax.Array,
    lam: jax.Array,
    unrolled: bool = False,
) -> jax.Array:
    """Targets ``G[t]`` of a rollout laid out [time, env, ...].

    ``next_value[t]`` is ``max_a Q(s'_t, a)`` for the observation after step t (the final
    observation where the episode ended). Backwards from the rollout's last step::

        G[T-1] = r[T-1] + gamma (1 - term[T-1]) next_value[T-1]
        G[t]   = r[t] + gamma (1 - term[t]) next_value[t]                        if done[t]
        G[t]   = r[t] + gamma ((1 - lam) next_value[t] + lam G[t+1])             otherwise

    so a time limit (``done`` without ``terminated``) bootstraps from the final observation and
    a terminal state does not bootstrap; returns never cross an episode boundary.

    ``unrolled``: the steps as straight-line code rather than a loop, each step's returns
    stored before the next step reads them (an optimization barrier; without it XLA fuses the
    whole chain into each later step's kernel, and the GPU compile took 3x as long). On a GPU
    every trip of a loop costs a round trip to the host, 32 of them per rollout of the
    RobotNav-v0 preset. The same operations either way.
    """

    def back(g_next, step):
        r, term, d, v = step
        mixed = jnp.where(d, v, (1.0 - lam) * v + lam * g_next)
        g = r + gamma * (1.0 - term.astype(r.dtype)) * mixed
        if unrolled:
            g = jax.lax.optimization_barrier(g)
        return g, g

    # the last step bootstraps fully: its "G[T]" is its own next value
    _, returns = jax.lax.scan(
        back,
        next_value[-1],
        (reward, terminated, done, next_value),
        reverse=True,
        unroll=unrolled,
    )
    return returns


def shuffled_rows(key: jax.Array, n: int, rounds: int = 4) -> jax.Array:
    """A random order of ``range(n)`` (int32), one epoch's minibatch rows.

    Where ``n`` is a power of two (every preset's rollout), a keyed bijection of the ``b``-bit
    row indices computed elementwise: ``rounds`` rounds of xor with a random key, product with
    a random odd number and xor with the upper half shifted down, each a bijection modulo
    ``2**b`` (the product carries low bits up, the shift high bits down). It replaces the two
    radix sorts of ``jax.random.permutation`` at every epoch's start (measured:
    docs/performance.md). Other ``n`` take
    ``jax.random.permutation``.
    """
    if n & (n - 1):
        return jax.random.permutation(key, n).astype(jnp.int32)
    bits = n.bit_length() - 1
    mask = jnp.uint32(n - 1)
    shift = max(1, (bits + 1) // 2)
    x = jnp.arange(n, dtype=jnp.uint32)
    for mixer, odd in jax.random.bits(key, (rounds, 2), jnp.uint32):
        x = ((x ^ mixer) * (odd | 1)) & mask
        x = x ^ (x >> shift)
    return x.astype(jnp.int32)
