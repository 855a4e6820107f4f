"""Environment base class: gymnax-1.0-style API with auto-reset and time limits in one place.

Subclasses implement ``reset_env`` (one fresh episode; keep it cheap, it runs on every
step under ``vmap``) and ``step_env`` (dynamics without time limit or reset). The base
class adds the time limit (``truncated``), auto-reset and ``info["final_observation"]``.

It also declares everything the layers above read of an env, so that they never look at an
env's own state or params: fixed test episodes (``reset_to``, ``reset_to_args``,
``reset_layout``, ``layouts_from``), a step without auto-reset (``step_no_reset``), evaluation
(``shortest_path_length``, ``step_length``, ``layout_index``, ``num_layouts``; success is
``info["goal_reached"]``), a curriculum's weighted layouts (``weighted_layouts``,
``EnvParams.layout_cdf``) and drawing (``sensor_ranges``, ``scene``). A new env is a folder
under ``jaxnav/envs/`` with its entries in ``jaxnav.registration``.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, ClassVar, Generic, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnav import backend, spaces


@struct.dataclass
class EnvState:
    """Fields every environment state has; subclasses add their own."""

    time: jax.Array  # steps taken in the current episode


@struct.dataclass
class EnvParams:
    """Fields every environment's parameters have; subclasses add their own, each named as the
    env config's field it comes from (``from_config``)."""

    max_steps_in_episode: int = 60
    # Where fresh episodes draw their bank layout (an env with ``weighted_layouts``): None,
    # uniformly; else float32[num_layouts], the cumulative probabilities of the layouts, last
    # 1 (``layout_from_cdf``). Not a config field: training sets it (``--curriculum``).
    layout_cdf: jax.Array | None = None

    @classmethod
    def from_config(cls, config: Any, **values: Any) -> Any:
        """These params from an env config: ``max_steps_in_episode`` from ``config.max_steps``,
        every other field from the config field of the same name, except those in ``values``
        (e.g. a layout bank) and ``layout_cdf``: a setting is declared once, in the config."""
        names = [f.name for f in dataclasses.fields(cls) if f.name not in values]
        own = ("max_steps_in_episode", "layout_cdf")
        taken = {n: getattr(config, n) for n in names if n not in own}
        return cls(max_steps_in_episode=config.max_steps, **taken, **values)


StateT = TypeVar("StateT", bound=EnvState)
ParamsT = TypeVar("ParamsT", bound=EnvParams)


class Environment(Generic[StateT, ParamsT]):
    """Stateless environment: all episode data lives in ``state``, all settings in ``params``."""

    family: ClassVar[str] = ""  # which presets train it (``jaxnav.presets``); "": none

    name: str = "Environment"
    # Whether ``step_env`` draws random numbers. If not, ``step`` hands its key to the
    # auto-reset alone and saves a key split per step (random numbers dominate the cost
    # of a cheap step).
    stochastic_step: bool = True
    # Per observation value, the number of categories a network should one-hot encode it
    # into (0: use it as a number); None: use every value as a number. Compact observations
    # (GridMaze's ``index``) keep env steps and replay small; ``QNetwork`` expands them.
    obs_onehot_sizes: tuple[int, ...] | None = None
    # ``step_batch`` builds fresh episodes for at most this fraction of a batch per step (the
    # envs whose episode ended), not for every env followed by a select. It pays where
    # ``reset_env`` is costly and episodes are long (the robot's ray casts), not where most
    # steps end an episode somewhere in a batch (grid). 1.0: reset every env and select.
    batch_reset_fraction: float = 1.0
    # Actions outside [0, num_actions) are clipped into it on every env (-1 acts as 0,
    # num_actions + 2 as num_actions - 1): indexing would remap them without a rule (it wraps
    # negatives). Debug option: ``env.check_actions = True`` raises on one instead (through a
    # host callback, so also inside ``jit``: the error then arrives as a JAX runtime error).
    check_actions: bool = False
    # Whether ``reset_env`` draws the layout by ``params.layout_cdf`` where it is set: what a
    # curriculum over the layouts (``jaxnav.train.curriculum``) needs of an env.
    weighted_layouts: bool = False

    @property
    def default_params(self) -> ParamsT:
        raise NotImplementedError

    @property
    def num_actions(self) -> int:
        raise NotImplementedError

    def action_space(self, params: ParamsT | None = None) -> spaces.Discrete:
        return spaces.Discrete(self.num_actions)

    def observation_space(self, params: ParamsT | None = None) -> spaces.Box:
        raise NotImplementedError

    # -- subclass hooks -------------------------------------------------------------
    def reset_env(self, key: jax.Array, params: ParamsT) -> tuple[jax.Array, StateT]:
        raise NotImplementedError

    def get_obs(self, state: StateT, params: ParamsT) -> jax.Array:
        """The observation of ``state``: a pure function of it, so auto-reset can select the
        (small) state first and build one observation instead of selecting two big ones."""
        raise NotImplementedError

    def step_env(
        self, key: jax.Array, state: StateT, action: jax.Array, params: ParamsT
    ) -> tuple[jax.Array, StateT, jax.Array, jax.Array, dict[str, Any]]:
        """One transition: ``(obs, state, reward, terminated, info)``; must advance ``time``."""
        raise NotImplementedError

    # -- evaluation hooks -------------------------------------------------------------
    # Defaults for an env with one layout and no known shortest paths; envs with a bank of
    # layouts (mazes) or with shortest paths override them.
    # -- what an exported policy says of the env (``jaxnav.export``) ----------------------
    def observation_layout(self, params: ParamsT) -> dict[str, Any]:
        """The observation value by value (``size``, ``entries`` with ``index``, ``name``,
        ``scale``, ``clip``, the frame stacking, what each name means), for a robot to build
        the same input; ``ValueError`` where the env does not describe it."""
        raise ValueError(f"{type(self).__name__}: no observation layout known for this env")

    def action_layout(self) -> list[dict[str, Any]]:
        """What each action index does, in the env's units."""
        raise ValueError(f"{type(self).__name__}: no action layout known for this env")

    def sensor_layout(self) -> dict[str, Any] | None:
        """The sensors and control period a policy was trained with; None without sensors."""
        return None

    def num_layouts(self, params: ParamsT) -> int:
        """Layouts (mazes) in the env's bank, a Python int; fresh episodes draw one of them."""
        return 1

    def reset_layout(
        self, key: jax.Array, params: ParamsT, layout: jax.Array
    ) -> tuple[jax.Array, StateT]:
        """A fresh episode like ``reset_env`` but in bank layout ``layout`` (start and goal still
        drawn from ``key``), so an evaluation can give every layout the same number of episodes.
        """
        del layout  # one layout
        return self.reset_env(key, params)

    def layout_index(self, state: StateT) -> jax.Array:
        """The bank layout ``state``'s episode runs in (int32; 0 with one layout)."""
        return jnp.zeros(state.time.shape, jnp.int32)

    def shortest_path_length(self, state: StateT, params: ParamsT) -> jax.Array:
        """Length of the shortest path from ``state``'s position to its goal, in the units of
        ``step_length``; -1 where it is not known."""
        return jnp.full(state.time.shape, -1.0)

    def step_length(self, state: StateT, next_state: StateT, params: ParamsT) -> jax.Array:
        """Path length travelled by the step from ``state`` to ``next_state`` (default: 1, one
        step). Summed over an episode and divided by ``shortest_path_length`` at its start, it
        gives the path ratio of ``jaxnav.evaluate``."""
        return jnp.ones(state.time.shape)

    def layouts_from(self, params: ParamsT, first: int) -> ParamsT:
        """``params`` whose bank keeps only layouts ``first``, ``first + 1``, ...: test
        episodes on layouts a run never trained on. One layout: ``first`` must be 0."""
        if first:
            raise ValueError(f"no layouts after {first - 1}: the env has one layout")
        return params

    # -- fixed episodes and drawing ---------------------------------------------------
    def reset_to(
        self,
        key: jax.Array,
        params: ParamsT,
        start: jax.Array,
        goal: jax.Array,
        layout: jax.Array | int = 0,
    ) -> tuple[jax.Array, StateT]:
        """An episode that starts at ``start`` with ``goal`` in bank layout ``layout``, in the
        env's own terms (a grid cell, a robot pose; ``reset_to_args`` gives them), for fixed
        test suites: every agent meets the same episodes."""
        raise NotImplementedError

    def reset_to_args(self, state: StateT) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``(start, goal, layout)`` for ``reset_to`` to start an episode where ``state``
        stands: for the state of a fresh reset, that very episode."""
        raise NotImplementedError

    def check_reset_to(self, params: ParamsT, start: Any, goal: Any, layout: Any = 0) -> None:
        """``ValueError`` naming the first start or goal of ``reset_to``'s arguments (one
        episode's or a batch's, concrete) that is off the map or in a blocked cell. ``reset_to``
        checks concrete arguments itself; under ``jit``/``vmap`` it cannot (it must stay a
        traceable function), so fixed suites call this on the host first."""
        raise NotImplementedError

    def sensor_ranges(self, state: StateT, params: ParamsT) -> jax.Array:
        """float32[R]: what each of the agent's R range sensors reads at ``state``, in the
        units of ``scene`` (R = 0, the default: no sensors to draw)."""
        del state, params
        return jnp.zeros((0,), jnp.float32)

    def scene(self, params: ParamsT, states: StateT, ranges: np.ndarray) -> dict[str, np.ndarray]:
        """One episode to draw, on the host: ``states`` (numpy leaves, leading axis the T + 1
        states from its start) and ``ranges`` ([T + 1, R], ``sensor_ranges`` at each) as
        numpy arrays in metres, or cells of side 1 with row 0 at the top: ``xy`` [T + 1, 2] and
        ``heading`` [T + 1] of the agent, ``lasers`` (the ranges), ``laser_angles`` [R] (each
        sensor's direction from the heading), ``goal`` [2], ``walls`` [K, 4] (x, y, width,
        height of each wall rectangle), ``arena`` (width, height), ``goal_radius`` and the
        agent's ``radius``."""
        raise NotImplementedError

    # -- public API -----------------------------------------------------------------
    def reset(self, key: jax.Array, params: ParamsT | None = None) -> tuple[jax.Array, StateT]:
        return self.reset_env(key, self.default_params if params is None else params)

    def step(
        self,
        key: jax.Array,
        state: StateT,
        action: jax.Array,
        params: ParamsT | None = None,
    ) -> tuple[jax.Array, StateT, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """Step and auto-reset: returns ``(obs, state, reward, terminated, truncated, info)``.

        When the episode ends, ``obs``/``state`` are those of a fresh episode and
        ``info["final_observation"]`` holds the last observation of the finished one.
        A time limit sets ``truncated`` only: it is not a terminal state for value targets.
        """
        params = self.default_params if params is None else params
        key_reset, obs_step, state_step, reward, terminated, truncated, info = self._transition(
            key, state, action, params
        )
        done = jnp.logical_or(terminated, truncated)
        state = self._auto_reset(key_reset, done, state_step, params)
        info["final_observation"] = obs_step
        return self.get_obs(state, params), state, reward, terminated, truncated, info

    def step_no_reset(
        self,
        key: jax.Array,
        state: StateT,
        action: jax.Array,
        params: ParamsT | None = None,
    ) -> tuple[jax.Array, StateT, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """``step`` without auto-reset: ``(obs, state, reward, terminated, truncated, info)``
        of the step itself, with the same time limit, so that an evaluation can keep an
        ended episode as it ended."""
        params = self.default_params if params is None else params
        _, obs, state, reward, terminated, truncated, info = self._transition(
            key, state, action, params
        )
        return obs, state, reward, terminated, truncated, info

    def step_batch(
        self,
        keys: jax.Array,
        state: StateT,
        action: jax.Array,
        params: ParamsT | None = None,
    ) -> tuple[jax.Array, StateT, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """``jax.vmap(self.step)`` over the leading axis of ``keys``, ``state`` and ``action``
        (``params`` shared), with the same results bit for bit, but fresh episodes built only
        for envs whose episode ended: at most ``batch_reset_fraction`` of the batch per step,
        every env (and a select) on a step where more end. Batches that
        ``backend.step_batch_as_vmap`` names (small ones on an accelerator) take
        ``vmap(step)``, which is faster there.

        For the top level: under another ``vmap`` (over seeds, say) the choice between the
        two becomes a select, both run, and this is no faster than ``vmap(step)``.
        """
        params = self.default_params if params is None else params
        num = keys.shape[0]
        budget = int(num * self.batch_reset_fraction)
        if budget >= num or backend.step_batch_as_vmap(num):
            return jax.vmap(self.step, in_axes=(0, 0, 0, None))(keys, state, action, params)
        budget = max(budget, 1)
        key_reset, obs_step, state_step, reward, terminated, truncated, info = jax.vmap(
            self._transition, in_axes=(0, 0, 0, None)
        )(keys, state, action, params)
        done = jnp.logical_or(terminated, truncated)

        def reset_ended(state_step: StateT) -> StateT:
            # the first ``budget`` ended envs; the index ``num`` pads and is dropped by the set
            idx = jnp.nonzero(done, size=budget, fill_value=num)[0]
            keys_ended = key_reset[jnp.minimum(idx, num - 1)]
            _, fresh = jax.vmap(self.reset_env, in_axes=(0, None))(keys_ended, params)
            return jax.tree.map(lambda s, f: s.at[idx].set(f, mode="drop"), state_step, fresh)

        def reset_every(state_step: StateT) -> StateT:
            auto_reset = jax.vmap(self._auto_reset, in_axes=(0, 0, 0, None))
            return auto_reset(key_reset, done, state_step, params)

        state = jax.lax.cond(done.sum() <= budget, reset_ended, reset_every, state_step)
        info["final_observation"] = obs_step
        obs = jax.vmap(self.get_obs, in_axes=(0, None))(state, params)
        return obs, state, reward, terminated, truncated, info

    def _valid_action(self, action: jax.Array) -> jax.Array:
        """``action`` clipped into [0, num_actions) (see ``check_actions``)."""
        action = jnp.asarray(action)
        if self.check_actions:
            jax.debug.callback(functools.partial(_check_action, n=self.num_actions), action)
        return jnp.clip(action, 0, self.num_actions - 1)

    def _auto_reset(
        self, key_reset: jax.Array, done: jax.Array, state: StateT, params: ParamsT
    ) -> StateT:
        """``state``, or a fresh episode's state where ``done``."""
        _, state_reset = self.reset_env(key_reset, params)  # its obs is unused: XLA drops it
        return jax.tree.map(lambda r, s: jnp.where(done, r, s), state_reset, state)

    def _transition(
        self, key: jax.Array, state: StateT, action: jax.Array, params: ParamsT
    ) -> tuple[jax.Array, jax.Array, StateT, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """``step_env`` plus the time limit: ``(key_reset, obs, state, reward, terminated,
        truncated, info)`` before any reset."""
        if self.stochastic_step:
            key_step, key_reset = jax.random.split(key)
        else:
            key_step = key_reset = key
        action = self._valid_action(action)
        obs, state, reward, terminated, info = self.step_env(key_step, state, action, params)
        terminated = jnp.asarray(terminated, dtype=bool)
        truncated = jnp.logical_and(
            state.time >= params.max_steps_in_episode, jnp.logical_not(terminated)
        )
        reward = jnp.asarray(reward, jnp.float32)
        return key_reset, obs, state, reward, terminated, truncated, dict(info)


def layout_from_cdf(u: jax.Array, cdf: jax.Array) -> jax.Array:
    """The layout (int32) that a uniform number ``u`` in [0, 1) draws from the cumulative
    probabilities ``cdf`` (``EnvParams.layout_cdf``): one binary search, not a random number
    per layout as ``jax.random.categorical`` draws."""
    # unrolled: a reset runs every step under vmap, and a loop there is a loop on the device
    index = jnp.searchsorted(cdf, u, side="right", method="scan_unrolled")
    return jnp.minimum(index, cdf.shape[0] - 1).astype(jnp.int32)  # a last entry just below 1


def _check_action(action: np.ndarray, n: int) -> None:
    """``ValueError`` naming an action outside [0, n) (``Environment.check_actions``)."""
    bad = np.asarray(action)[(np.asarray(action) < 0) | (np.asarray(action) >= n)]
    if bad.size:
        raise ValueError(f"action {int(bad.ravel()[0])}: outside [0, {n})")


def is_concrete(*values: Any) -> bool:
    """Whether every array in ``values`` holds values (no ``jit``/``vmap`` tracer)."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(values))
