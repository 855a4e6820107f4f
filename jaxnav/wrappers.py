"""gymnax-0.0.x API on top of our gymnax-1.0-style environments.

Our ``Environment.step`` returns six values, ``(obs, state, reward, terminated, truncated,
info)``. Trainers written for gymnax 0.0.x (rejax 0.1.x, PureJaxRL) unpack five,
``(obs, state, reward, done, info)``, and pick their network head with
``isinstance(space, gymnax.environments.spaces.Discrete)``. ``GymnaxV0`` gives them both, so
they run on our environments unmodified.

Their networks read observations as numbers: on GridMaze, make the env with
``obs_mode="onehot"`` (the default ``index`` codes are meant for ``QNetwork``'s one-hot input,
``env.obs_onehot_sizes``).

Such trainers treat ``done`` as terminal and take the auto-reset ``obs`` as the next
observation, so a time limit is learned as a terminal state. ``info`` keeps what a correct
target needs: ``"terminated"``, ``"truncated"``, ``"discount"`` (``1 - terminated``, as
gymnax's ``info["discount"]``) and ``"final_observation"``.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

from jaxnav import spaces
from jaxnav.environment import Environment, EnvParams, EnvState

try:  # trainers check isinstance against gymnax's own classes
    from gymnax.environments import spaces as gymnax_spaces
except ImportError:  # gymnax is optional
    gymnax_spaces = None

Space = Any  # a gymnax space when gymnax is importable, else one of jaxnav.spaces


def to_gymnax_space(space: Space) -> Space:
    """The gymnax equivalent of a ``jaxnav.spaces`` space (``space`` itself without gymnax)."""
    if gymnax_spaces is None:
        return space
    if isinstance(space, spaces.Discrete):
        out = gymnax_spaces.Discrete(space.n)
        out.dtype = space.dtype
        return out
    if isinstance(space, spaces.Box):
        return gymnax_spaces.Box(space.low, space.high, space.shape, space.dtype)
    raise TypeError(f"no gymnax equivalent for {space!r}")


class GymnaxV0:
    """``env`` with gymnax 0.0.x's ``step``, ``reset`` and spaces; other attributes fall
    through to ``env``."""

    def __init__(self, env: Environment) -> None:
        self._env = env

    def __getattr__(self, name: str) -> Any:
        if name == "_env":  # not set yet (copy/pickle): don't recurse
            raise AttributeError(name)
        return getattr(self._env, name)

    def __repr__(self) -> str:
        return f"GymnaxV0({self._env.name})"

    @property
    def unwrapped(self) -> Environment:
        return self._env

    @property
    def default_params(self) -> EnvParams:
        return self._env.default_params

    @property
    def num_actions(self) -> int:
        return self._env.num_actions

    @property
    def name(self) -> str:
        return self._env.name

    def action_space(self, params: EnvParams | None = None) -> Space:
        return to_gymnax_space(self._env.action_space(params))

    def observation_space(self, params: EnvParams | None = None) -> Space:
        return to_gymnax_space(self._env.observation_space(params))

    @partial(jax.jit, static_argnames=("self",))
    def reset(self, key: jax.Array, params: EnvParams | None = None) -> tuple[jax.Array, EnvState]:
        return self._env.reset(key, params)

    @partial(jax.jit, static_argnames=("self",))
    def step(
        self,
        key: jax.Array,
        state: EnvState,
        action: jax.Array | int,
        params: EnvParams | None = None,
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict[str, Any]]:
        """``(obs, state, reward, done, info)`` with ``done = terminated | truncated`` (bool)."""
        obs, state, reward, terminated, truncated, info = self._env.step(key, state, action, params)
        info = {
            **info,
            "terminated": terminated,
            "truncated": truncated,
            "discount": 1.0 - terminated.astype(jnp.float32),
        }
        return obs, state, reward, jnp.logical_or(terminated, truncated), info
