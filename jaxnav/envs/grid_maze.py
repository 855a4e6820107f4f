"""GridMaze: the paper's discrete 2D experiment (Sec. IV-A), in pure JAX.

A robot moves up/down/left/right on a square grid with obstacles and must reach a goal.
Reward: ``goal_reward`` (+4) on reaching the goal, ``collision_reward`` (-1) for moving into
an obstacle or off the grid (the robot stays put), ``step_reward`` (0) otherwise. Goal and
collision terminate; the time limit (60 steps) truncates.

Layouts live in a *bank* built once by ``make``: for each layout the free cells, a set of
goal cells and the BFS distance field from each goal. A reset is then a handful of gathers
(a random layout, goal and start), so auto-reset costs about as much as a step, and the
shortest path of every episode is known for free (``info["shortest_path"]``).

``GridMaze-v0`` has one layout (picked by ``layout_seed``) and uses every free cell as a goal.
``GridMaze-Random-v0`` draws a layout from a bank of ``num_layouts`` per episode.

Observation modes (all encode the paper's information: robot, goal and obstacle positions):

- ``paper``: the literal encoding: robot (x, y), goal (x, y) and every obstacle's (x, y),
  divided by ``size - 1``. Obstacle lists are padded to the bank's largest by repeating the
  first obstacle (a duplicate adds no information); a layout without obstacles shows one at
  (0, 0), the same in every observation.
- ``onehot`` (chosen by measurement, see docs/paper.md): one-hot robot row, robot column, goal row
  and goal column, whether each of the 4 neighbours is blocked, and the goal's offset
  (drow, dcol) in cells, as int8 (int16 above size 128). For a fixed layout the obstacle
  coordinates are constants, so the network learns them from the rewards instead of reading
  them.
- ``index`` (default of GridMaze-v0): the same information before one-hot encoding: robot
  row, robot column, goal row, goal column, the 4 neighbour bits and the offset, 10 int8
  values. ``env.obs_onehot_sizes`` says which values are categories, and jaxnav's
  ``QNetwork`` expands them to the ``onehot`` vector, so a DQN learns exactly as with
  ``onehot`` while the env writes, and replay stores, 10 bytes per observation instead of 66.
  An MLP of your own should use ``onehot``.
- ``sensor`` (default of GridMaze-Random-v0): what a robot with range sensors would see:
  the occupancy of the (2r+1)^2 window around the robot (off-grid counts as blocked), the
  free distance along each of the 4 grid directions / (size - 1), and the goal's offset.
  Coordinates of a changing obstacle set do not generalize in an MLP; local sensing does.

``waypoint_cells`` (k > 0, ``sensor`` only; off by default, so the paper's GridMaze-v0 is
unchanged) appends a global planner's hint, as ``RobotNav-v0``'s waypoint: the offset
(drow, dcol) / k from the robot to the cell k moves ahead on a shortest path to the goal
(descending the goal's BFS distance field; ties go to up, down, left, right in that order),
the goal itself once it is within k moves. A point several cells ahead, not the next cell:
with k = 1 the hint would be the optimal action itself. With k >= 2 the policy must still
combine it with the occupancy window (an offset such as (-1, +1) leaves two moves, and only
free ones lead there), and with larger k the path bends around obstacles between the robot
and the point. ``make`` precomputes every cell's waypoint for each goal of the bank
(``waypoint_offsets``: 2 int8 per cell and goal), so the hint is one gather per step (8-10%
fewer env steps/s than without it at 4096-16384 envs on a 2-core CPU,
``env_throughput_grid_waypoint`` in docs/results-history.md). The bank knows its goal cells
only: for a goal given to ``reset_to`` that is not one of them the hint points at the goal,
each axis clipped to k.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnav import spaces
from jaxnav.environment import Environment, EnvParams, EnvState, is_concrete, layout_from_cdf
from jaxnav.envs.maze_algorithms import (
    bank_distances,
    check_fields,
    check_int,
    fill_pockets,
    first_blocked_cell,
    is_number,
    shortest_path_length,
)

# (drow, dcol) of the actions up, down, left, right
ACTION_NAMES = ("up", "down", "left", "right")
MOVES = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int32)
OBS_MODES = ("index", "onehot", "paper", "sensor")
# layout_seed of held-out test banks: its layouts are none of a training bank's of the default
# layout_seed 0 (tests/test_grid_maze.py checks this for the default generator)
HELD_OUT_LAYOUT_SEED = 1_000_003


@dataclasses.dataclass(frozen=True)
class GridMazeConfig:
    """Everything that defines a GridMaze; ``jaxnav.make(id, **overrides)`` replaces fields."""

    # the fields that choose the layouts (a policy tested on other mazes keeps the rest)
    MAZE_FIELDS: ClassVar[frozenset[str]] = frozenset(
        {"size", "obstacle_density", "layout_seed", "random_layouts", "num_layouts"}
        | {"goals_per_layout"}
    )

    size: int = 15
    obstacle_density: float = 0.2
    layout_seed: int = 0
    random_layouts: bool = False
    num_layouts: int = 1024  # bank size when random_layouts
    goals_per_layout: int = 16  # goal cells per layout when random_layouts
    obs_mode: str = "index"
    sensor_radius: int = 2
    waypoint_cells: int = 0  # sensor: offset to the cell k moves ahead on a shortest path; 0 off
    max_steps: int = 60
    goal_reward: float = 4.0
    collision_reward: float = -1.0
    step_reward: float = 0.0

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        check_int("size", self.size, 2, 255)
        check_int("layout_seed", self.layout_seed, 0, 2**32 - 1)
        check_int("num_layouts", self.num_layouts, 1, 1_000_000)
        check_int("goals_per_layout", self.goals_per_layout, 1, 1_000_000)
        check_int("sensor_radius", self.sensor_radius, 1, 64)
        check_int("waypoint_cells", self.waypoint_cells, 0, 64)  # offsets fit in int8
        check_int("max_steps", self.max_steps, 1, 1_000_000)
        if not isinstance(self.random_layouts, bool):
            raise ValueError(f"random_layouts={self.random_layouts!r}: must be true or false")
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode={self.obs_mode!r}: must be one of {', '.join(OBS_MODES)}")
        if self.waypoint_cells and self.obs_mode != "sensor":
            raise ValueError(
                f"waypoint_cells={self.waypoint_cells}: the waypoint is part of the sensor "
                f"observation; use obs_mode='sensor' (not {self.obs_mode!r}) or waypoint_cells=0"
            )
        d = self.obstacle_density
        if not is_number(d) or not 0.0 <= d < 1.0:
            raise ValueError(f"obstacle_density={d!r}: must be a number in [0, 1)")
        if self.size * self.size - round(d * self.size * self.size) < 2:
            raise ValueError(
                f"obstacle_density={d!r}: more obstacles than a {self.size}x{self.size} grid "
                "can hold with a free start and goal"
            )
        for name in (f.name for f in dataclasses.fields(self) if "reward" in f.name):
            v = getattr(self, name)
            if not is_number(v) or not np.isfinite(v):
                raise ValueError(f"{name}={v!r}: must be a finite number")
        check_fields(self)
        # the bank holds a BFS distance field (int16 per cell) for every goal of every layout,
        # and with the waypoint each cell's offset to it (2 int8)
        cells = self.size * self.size
        layouts, goals = (
            (self.num_layouts, self.goals_per_layout) if self.random_layouts else (1, cells)
        )
        gib = layouts * goals * cells * (4 if self.waypoint_cells else 2) / 2**30
        if gib > MAX_BANK_GIB:
            raise ValueError(
                f"size={self.size}, num_layouts={self.num_layouts}, goals_per_layout="
                f"{self.goals_per_layout}: the layout bank's distance fields would take "
                f"{gib:.1f} GiB (at most {MAX_BANK_GIB})"
            )
        # building the bank holds more per cell than its distance fields (random draws, sort
        # orders, cell lists): ~53 bytes per layout cell measured with one goal per layout
        build = layouts * cells * (BANK_BUILD_BYTES_PER_CELL + 2 * goals) / 2**30
        if build > MAX_BANK_BUILD_GIB:
            raise ValueError(
                f"size={self.size}, num_layouts={self.num_layouts}, goals_per_layout="
                f"{self.goals_per_layout}: building the layout bank would take about "
                f"{build:.1f} GiB of memory (at most {MAX_BANK_BUILD_GIB}); use fewer or "
                "smaller layouts"
            )


MAX_BANK_GIB = 2
BANK_BUILD_BYTES_PER_CELL = 56
MAX_BANK_BUILD_GIB = 8


def default_config() -> GridMazeConfig:
    return GridMazeConfig()


# ---------------------------------------------------------------------------- layouts
@struct.dataclass
class LayoutBank:
    """Pre-generated layouts; every array has the layout index first."""

    obstacles: jax.Array  # bool[L, S, S]
    free_cells: jax.Array  # int32[L, F, 2] (row, col), padded with the first free cell
    num_free: jax.Array  # int32[L]
    goal_slots: jax.Array  # int32[L, P] indices into free_cells
    goal_distance: jax.Array  # int16[L, P, S, S] BFS steps to the goal, -1 where unreachable
    obstacle_cells: jax.Array  # int32[L, O, 2], padded by repeating the first obstacle
    blocked_moves: jax.Array  # uint8[L, S, S]: bit a set if action a from the cell collides
    # only built for the waypoint (None without it): int16[L, S, S], a goal slot whose goal is
    # the cell, -1 if none; int8[L, P, S, S, 2], each cell's offset to its waypoint
    goal_slot_of: jax.Array | None = None
    waypoint_offset: jax.Array | None = None

    @property
    def num_layouts(self) -> int:
        return self.obstacles.shape[0]


def generate_layouts(size: int, density: float, num: int, seed: int) -> np.ndarray:
    """``num`` layouts with ``round(density * size^2)`` random obstacles each, then every free
    cell outside the largest connected free region filled in, so that any two free cells are
    connected. The density rises above the requested one as pockets fill: on 15x15, 0.2 gives
    about 0.21 and 0.3 about 0.36."""
    rng = np.random.default_rng(seed)
    cells = size * size
    k = round(density * cells)
    order = np.argsort(rng.random((num, cells)), axis=1)
    obstacles = np.zeros((num, cells), dtype=bool)
    np.put_along_axis(obstacles, order[:, :k], True, axis=1)
    return fill_pockets(obstacles.reshape(num, size, size), ties="last")


@functools.partial(jax.jit, static_argnums=1)
def waypoint_offsets(goal_distance: jax.Array, k: int) -> jax.Array:
    """int8[..., S, S, 2]: from every cell, the offset (drow, dcol) to the cell ``k`` moves
    ahead on a shortest path to the goal of each distance field ``goal_distance[..., S, S]``
    (BFS steps, -1 blocked): ``k`` steps down the field, each to the lowest of the 4
    neighbours (the first of equals in the order up, down, left, right) while it is lower than
    the cell, so the goal itself once it is nearer. Obstacle cells get meaningless offsets."""
    *batch, h, w = goal_distance.shape
    far = jnp.iinfo(jnp.int32).max  # obstacles, unreachable cells and off the grid
    moves = jnp.asarray(MOVES)
    start = jnp.stack(jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij"), axis=-1)

    def one_field(dist: jax.Array) -> jax.Array:
        padded = jnp.pad(jnp.where(dist >= 0, dist.astype(jnp.int32), far), 1, constant_values=far)
        cell = start + 1  # in padded coordinates
        here = padded[cell[..., 0], cell[..., 1]]
        for _ in range(k):  # a few static steps down the field, every cell at once
            nb = cell[:, :, None, :] + moves  # [h, w, 4, 2]
            around = padded[nb[..., 0], nb[..., 1]]
            best = jnp.argmin(around, axis=-1)  # the first of equals: up, down, left, right
            lowest = jnp.take_along_axis(around, best[..., None], axis=-1)[..., 0]
            better = lowest < here
            cell = jnp.where(better[..., None], cell + moves[best], cell)
            here = jnp.where(better, lowest, here)
        return (cell - 1 - start).astype(jnp.int8)

    fields = goal_distance.reshape(-1, h, w)
    # one layout's worth of fields at a time: the neighbour tables of a whole bank are large
    per_chunk = max(1, math.prod(batch[1:]))
    out = jax.lax.map(jax.vmap(one_field), fields.reshape(-1, per_chunk, h, w))
    return out.reshape(*batch, h, w, 2)


def build_bank(cfg: GridMazeConfig, obstacles: np.ndarray | None = None) -> LayoutBank:
    """The bank of ``cfg``'s generated layouts, or of ``obstacles`` (bool[L, S, S], e.g. a
    hand-made layout: L = 1 unless ``cfg.random_layouts``, each layout one connected free
    region) with ``cfg``'s other settings."""
    if obstacles is None:
        num = cfg.num_layouts if cfg.random_layouts else 1
        obstacles = generate_layouts(cfg.size, cfg.obstacle_density, num, cfg.layout_seed)
    num = obstacles.shape[0]
    cells = cfg.size * cfg.size
    free_mask = ~obstacles.reshape(num, cells)
    num_free = free_mask.sum(axis=1)
    if num_free.min() < 2:
        raise ValueError(
            f"obstacle_density={cfg.obstacle_density!r}: layout_seed={cfg.layout_seed} leaves "
            "fewer than 2 connected free cells; lower the density"
        )
    rc = np.stack(np.divmod(np.arange(cells), cfg.size), axis=1).astype(np.int32)
    # free cells first (stable order), padded with the first free cell
    order = np.argsort(~free_mask, axis=1, kind="stable")
    fmax = int(num_free.max())
    free_cells = rc[order[:, :fmax]]
    free_cells = np.where(
        (np.arange(fmax)[None, :] < num_free[:, None])[..., None], free_cells, free_cells[:, :1]
    )
    if cfg.random_layouts:
        rng = np.random.default_rng(cfg.layout_seed + 1)
        goal_slots = np.floor(rng.random((num, cfg.goals_per_layout)) * num_free[:, None]).astype(
            np.int32
        )
    else:
        goal_slots = np.arange(fmax, dtype=np.int32)[None, :]  # every free cell is a goal
    goals = np.take_along_axis(free_cells, goal_slots[..., None], axis=1)
    dist = bank_distances(jnp.asarray(obstacles), jnp.asarray(goals))
    num_obs = (~free_mask).sum(axis=1)
    omax = max(1, int(num_obs.max()))
    order_o = np.argsort(free_mask, axis=1, kind="stable")[:, :omax]
    obstacle_cells = rc[order_o]
    obstacle_cells = np.where(
        (np.arange(omax)[None, :] < num_obs[:, None])[..., None],
        obstacle_cells,
        obstacle_cells[:, :1],
    )
    walled = np.pad(obstacles, ((0, 0), (1, 1), (1, 1)), constant_values=True)
    s = cfg.size
    blocked_moves = np.zeros((num, s, s), np.uint8)
    for a, (dr, dc) in enumerate(MOVES):
        blocked_moves |= walled[:, 1 + dr : 1 + dr + s, 1 + dc : 1 + dc + s].astype(np.uint8) << a
    goal_slot_of = waypoint_offset = None
    if cfg.waypoint_cells:
        slot_map = np.full((num, s, s), -1, np.int16)
        rows = np.repeat(np.arange(num), goal_slots.shape[1])
        slot_map[rows, goals[..., 0].ravel(), goals[..., 1].ravel()] = np.tile(
            np.arange(goal_slots.shape[1], dtype=np.int16), num
        )
        goal_slot_of = jnp.asarray(slot_map)
        waypoint_offset = waypoint_offsets(dist, cfg.waypoint_cells)
    return LayoutBank(
        goal_slot_of=goal_slot_of,
        waypoint_offset=waypoint_offset,
        blocked_moves=jnp.asarray(blocked_moves),
        obstacles=jnp.asarray(obstacles),
        free_cells=jnp.asarray(free_cells, jnp.int32),
        num_free=jnp.asarray(num_free, jnp.int32),
        goal_slots=jnp.asarray(goal_slots, jnp.int32),
        goal_distance=dist,
        obstacle_cells=jnp.asarray(obstacle_cells, jnp.int32),
    )


# ------------------------------------------------------------------------ environment
def _reset_bits(key: jax.Array) -> jax.Array:
    """Two random 32-bit words for a reset, from the key's own 64 bits through the murmur3
    finalizer. The random numbers of a reset cost more than the rest of an auto-reset step
    together, and one threefry draw costs 3.5x this (benchmarks/env_throughput.py); keys are
    fresh splits (or user seeds, which the finalizer's avalanche spreads), so this is enough
    to pick a start and goal. Statistical quality is not needed beyond that."""
    data = jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key
    data = data.reshape(-1).astype(jnp.uint32)
    w0, w1 = data[0], data[-1]

    def fmix(x):
        x = x ^ (x >> 16)
        x = x * jnp.uint32(0x85EBCA6B)
        x = x ^ (x >> 13)
        x = x * jnp.uint32(0xC2B2AE35)
        return x ^ (x >> 16)

    a = fmix(w0 * jnp.uint32(0x9E3779B1) ^ fmix(w1 + jnp.uint32(0x7F4A7C15)))
    return jnp.stack([a, fmix(a ^ w1 ^ jnp.uint32(0x632BE5AB))])


def _pick(random_bits: jax.Array, n: jax.Array | int, num_bits: int = 24) -> jax.Array:
    """A uniform integer in [0, n) from ``num_bits`` random bits (bias below n / 2^num_bits)."""
    u = random_bits.astype(jnp.float32) * (1.0 / (1 << num_bits))
    return jnp.minimum((u * n).astype(jnp.int32), n - 1)


@struct.dataclass
class GridMazeState(EnvState):
    pos: jax.Array  # int32[2] robot (row, col)
    goal: jax.Array  # int32[2] goal (row, col)
    layout: jax.Array  # int32 index into the bank
    shortest_path: jax.Array  # int32 BFS length from the episode's start to the goal


@struct.dataclass(kw_only=True)
class GridMazeParams(EnvParams):
    """The config's rewards (``EnvParams.from_config``) and the layout bank."""

    goal_reward: float
    collision_reward: float
    step_reward: float
    bank: LayoutBank


class GridMaze(Environment[GridMazeState, GridMazeParams]):
    """Grid navigation to a goal among obstacles; see the module docstring."""

    family: ClassVar[str] = "grid"  # which presets train it (``jaxnav.presets``)

    stochastic_step = False  # moves are deterministic
    weighted_layouts = True  # reset_env reads params.layout_cdf

    def observation_layout(self, params: GridMazeParams) -> dict[str, Any]:
        entries = [{"index": i, **e} for i, e in enumerate(grid_layout(self, params))]
        return {
            "size": len(entries),
            "frames": 1,
            "frame_size": len(entries),
            "obs_mode": self.config.obs_mode,
            "env_dtype": str(np.dtype(self.observation_space(params).dtype)),
            "entries": entries,
            "quantities": GRID_QUANTITIES,
            "value": "raw quantity x scale",
        }

    def action_layout(self) -> list[dict[str, Any]]:
        return [
            {"index": i, "name": n, "drow": int(d[0]), "dcol": int(d[1])}
            for i, (n, d) in enumerate(zip(ACTION_NAMES, MOVES, strict=True))
        ]

    def __init__(self, config: GridMazeConfig | None = None, name: str = "GridMaze-v0"):
        """``config`` as ``jaxnav.make`` validated it (or the default one)."""
        self.config = default_config() if config is None else config
        self.name = name
        self.size = self.config.size
        self._bank = build_bank(self.config)

    @property
    def default_params(self) -> GridMazeParams:
        return GridMazeParams.from_config(self.config, bank=self._bank)

    @property
    def num_actions(self) -> int:
        return len(ACTION_NAMES)

    def observation_space(self, params: GridMazeParams | None = None) -> spaces.Box:
        if self.config.obs_mode in ("index", "onehot"):  # cells and bits: exact in integers
            return spaces.Box(1 - self.size, self.size - 1, (self.obs_size,), self._int_dtype)
        return spaces.Box(-1.0, 1.0, (self.obs_size,), jnp.float32)

    @property
    def _int_dtype(self) -> Any:
        """The smallest integer type that holds a cell offset, 1 - size .. size - 1."""
        return jnp.int8 if self.size <= 128 else jnp.int16

    @property
    def obs_onehot_sizes(self) -> tuple[int, ...] | None:
        """For ``index``: the number of categories of each value (0: a plain number)."""
        if self.config.obs_mode != "index":
            return None
        return (self.size,) * 4 + (0,) * 6

    @property
    def obs_size(self) -> int:
        s, mode = self.size, self.config.obs_mode
        if mode == "index":
            return 4 + 4 + 2
        if mode == "onehot":
            return 4 * s + 4 + 2
        if mode == "paper":
            return 4 + 2 * self._bank.obstacle_cells.shape[1]
        hint = 2 if self.config.waypoint_cells else 0
        return (2 * self.config.sensor_radius + 1) ** 2 + 4 + 2 + hint

    # -- episodes -----------------------------------------------------------------
    def reset_env(self, key: jax.Array, params: GridMazeParams) -> tuple[jax.Array, GridMazeState]:
        bits = _reset_bits(key)
        if params.layout_cdf is None:
            layout = _pick(bits[0] >> 8, params.bank.num_layouts)
        else:  # the same 24 bits as a number in [0, 1)
            u = (bits[0] >> 8).astype(jnp.float32) * (1.0 / (1 << 24))
            layout = layout_from_cdf(u, params.layout_cdf)
        return self._reset_in(bits, layout, params)

    def reset_layout(
        self, key: jax.Array, params: GridMazeParams, layout: jax.Array
    ) -> tuple[jax.Array, GridMazeState]:
        """``reset_env`` in bank layout ``layout`` (the same start and goal slots from ``key``)."""
        return self._reset_in(_reset_bits(key), jnp.asarray(layout, jnp.int32), params)

    def _reset_in(
        self, bits: jax.Array, layout: jax.Array, params: GridMazeParams
    ) -> tuple[jax.Array, GridMazeState]:
        bank = params.bank
        slot = _pick(((bits[0] & 0xFF) << 8) | (bits[1] & 0xFF), bank.goal_slots.shape[1], 16)
        goal_idx = bank.goal_slots[layout, slot]
        start_idx = _pick(bits[1] >> 8, bank.num_free[layout] - 1)
        start_idx = start_idx + (start_idx >= goal_idx)  # any free cell but the goal's
        start = bank.free_cells[layout, start_idx]
        goal = bank.free_cells[layout, goal_idx]
        shortest = bank.goal_distance[layout, slot, start[0], start[1]].astype(jnp.int32)
        return self._start(start, goal, layout, shortest, params)

    def reset_to(
        self,
        key: jax.Array,
        params: GridMazeParams,
        start: jax.Array,
        goal: jax.Array,
        layout: jax.Array | int = 0,
    ) -> tuple[jax.Array, GridMazeState]:
        """Start an episode at a given start and goal cell (row, col) in bank layout ``layout``,
        for fixed test suites. The shortest path is computed by BFS (-1 if unreachable)."""
        del key  # deterministic; kept for a uniform signature
        if is_concrete(params, start, goal, layout):  # under jit/vmap: check_reset_to first
            self.check_reset_to(params, start, goal, layout)
        start = jnp.asarray(start, jnp.int32)
        goal = jnp.asarray(goal, jnp.int32)
        layout = jnp.asarray(layout, jnp.int32)
        obstacles = params.bank.obstacles[layout]
        shortest = shortest_path_length(obstacles, start, goal)
        return self._start(start, goal, layout, shortest, params)

    def check_reset_to(
        self, params: GridMazeParams, start: Any, goal: Any, layout: Any = 0
    ) -> None:
        walls = np.asarray(params.bank.obstacles)
        for name, cells in (("start", start), ("goal", goal)):
            bad = first_blocked_cell(walls, layout, cells)
            if bad is not None:
                cell = np.asarray(cells).reshape(-1, 2)[bad[0]].tolist()
                raise ValueError(f"reset_to {name}={cell}: {bad[1]}")

    def _start(self, start, goal, layout, shortest, params) -> tuple[jax.Array, GridMazeState]:
        state = GridMazeState(
            time=jnp.zeros((), jnp.int32),
            pos=start,
            goal=goal,
            layout=layout,
            shortest_path=jnp.asarray(shortest, jnp.int32),
        )
        return self.get_obs(state, params), state

    def reset_to_args(self, state: GridMazeState) -> tuple[jax.Array, jax.Array, jax.Array]:
        """The robot's cell, the goal's cell and the layout, as ``reset_to`` takes them."""
        return state.pos, state.goal, state.layout

    def num_layouts(self, params: GridMazeParams) -> int:
        return params.bank.num_layouts

    def layouts_from(self, params: GridMazeParams, first: int) -> GridMazeParams:
        return params.replace(bank=jax.tree.map(lambda x: x[first:], params.bank))

    def layout_index(self, state: GridMazeState) -> jax.Array:
        return state.layout

    def shortest_path_length(self, state: GridMazeState, params: GridMazeParams) -> jax.Array:
        """BFS moves from the episode's start to its goal (-1 if unreachable); with the
        default ``step_length`` of 1 a path ratio is steps / shortest path, as in the paper."""
        return state.shortest_path.astype(jnp.float32)

    def step_env(
        self, key: jax.Array, state: GridMazeState, action: jax.Array, params: GridMazeParams
    ) -> tuple[jax.Array, GridMazeState, jax.Array, jax.Array, dict[str, jax.Array]]:
        target = state.pos + jnp.asarray(MOVES)[action]
        blocked = ((self._moves_blocked(params, state) >> action) & 1).astype(bool)
        pos = jnp.where(blocked, state.pos, target)
        at_goal = jnp.logical_and(jnp.all(pos == state.goal), jnp.logical_not(blocked))
        r_goal = jnp.where(at_goal, params.goal_reward, 0.0)
        r_collision = jnp.where(blocked, params.collision_reward, 0.0)
        r_step = jnp.where(blocked | at_goal, 0.0, params.step_reward)
        state = state.replace(pos=pos, time=state.time + 1)
        info = {
            "goal_reached": at_goal,
            "collision": blocked,
            "shortest_path": state.shortest_path,
            "reward_goal": r_goal,
            "reward_collision": r_collision,
            "reward_step": r_step,
        }
        reward = r_goal + r_collision + r_step
        return self.get_obs(state, params), state, reward, at_goal | blocked, info

    def scene(
        self, params: GridMazeParams, states: GridMazeState, ranges: np.ndarray
    ) -> dict[str, np.ndarray]:
        """Cells of side 1 (cell (row, col) has its centre at (col + 0.5, size - row - 0.5)),
        the obstacles as unit squares; no heading, no sensors to draw."""
        size = self.size
        to_xy = lambda rc: np.stack([rc[..., 1] + 0.5, size - rc[..., 0] - 0.5], -1)  # noqa: E731
        blocked = np.argwhere(np.asarray(params.bank.obstacles[int(states.layout[0])]))
        cells = to_xy(blocked) - 0.5
        return {
            "xy": to_xy(states.pos).astype(np.float32),
            "heading": np.zeros(len(states.pos), np.float32),
            "lasers": ranges,
            "laser_angles": np.zeros(0, np.float32),
            "goal": to_xy(states.goal[0]).astype(np.float32),
            "walls": np.concatenate([cells, np.ones_like(cells)], axis=1).astype(np.float32),
            "arena": np.array([size, size], np.float32),
            "goal_radius": np.float32(0.4),
            "radius": np.float32(0.3),
        }

    # -- observation --------------------------------------------------------------
    def _moves_blocked(self, params: GridMazeParams, state: GridMazeState) -> jax.Array:
        """Bit a: whether action a collides (one gather from the precomputed table)."""
        return params.bank.blocked_moves[state.layout, state.pos[0], state.pos[1]]

    def _blocked(self, params: GridMazeParams, layout: jax.Array, cell: jax.Array) -> jax.Array:
        """Whether ``cell`` (..., 2) of ``layout`` is off the grid or an obstacle."""
        inside = jnp.all((cell >= 0) & (cell < self.size), axis=-1)
        c = jnp.clip(cell, 0, self.size - 1)
        # one gather of the cells, not a copy of the whole layout first
        return jnp.logical_or(~inside, params.bank.obstacles[layout, c[..., 0], c[..., 1]])

    def get_obs(self, state: GridMazeState, params: GridMazeParams) -> jax.Array:
        s, mode = self.size, self.config.obs_mode
        scale = 1.0 / max(s - 1, 1)
        if mode == "paper":
            xy = lambda rc: rc[..., ::-1].astype(jnp.float32) * scale  # noqa: E731
            obs_cells = params.bank.obstacle_cells[state.layout]
            return jnp.concatenate([xy(state.pos), xy(state.goal), xy(obs_cells).ravel()])
        if mode in ("index", "onehot"):
            bits = self._moves_blocked(params, state)
            neighbours = (bits >> jnp.arange(4, dtype=jnp.uint8)) & 1
            offset = state.goal - state.pos  # in cells
            ints = self._int_dtype
            if mode == "index":  # the env's throughput is bound by writing observations
                return jnp.concatenate([state.pos, state.goal, neighbours, offset]).astype(ints)
            return jnp.concatenate(
                [
                    jax.nn.one_hot(state.pos[0], s, dtype=ints),
                    jax.nn.one_hot(state.pos[1], s, dtype=ints),
                    jax.nn.one_hot(state.goal[0], s, dtype=ints),
                    jax.nn.one_hot(state.goal[1], s, dtype=ints),
                    neighbours.astype(ints),
                    offset.astype(ints),
                ]
            )
        r = self.config.sensor_radius
        d = np.arange(-r, r + 1, dtype=np.int32)
        window = np.stack(np.meshgrid(d, d, indexing="ij"), axis=-1).reshape(-1, 2)
        occupancy = self._blocked(params, state.layout, state.pos + jnp.asarray(window))
        steps = np.arange(1, s, dtype=np.int32)
        rays = MOVES[:, None, :] * steps[None, :, None]  # [4, s-1, 2]
        hit = self._blocked(params, state.layout, state.pos + jnp.asarray(rays))
        free_run = jnp.argmax(jnp.concatenate([hit, jnp.ones((4, 1), bool)], axis=1), axis=1)
        offset = (state.goal - state.pos).astype(jnp.float32) * scale
        parts = [occupancy.astype(jnp.float32), free_run.astype(jnp.float32) * scale, offset]
        if self.config.waypoint_cells:
            to_waypoint = self.waypoint(state, params) - state.pos
            parts.append(to_waypoint.astype(jnp.float32) / self.config.waypoint_cells)
        return jnp.concatenate(parts)

    def waypoint(self, state: GridMazeState, params: GridMazeParams) -> jax.Array:
        """(row, col) of the cell ``waypoint_cells`` moves ahead of the robot on a shortest
        path to the goal, the goal once it is nearer; for a goal without a distance field in
        the bank (``reset_to``), the goal clipped to ``waypoint_cells`` from the robot on each
        axis. See the module docstring."""
        k = self.config.waypoint_cells
        bank = params.bank
        # -1: the bank has no distance field for this goal
        slot = bank.goal_slot_of[state.layout, state.goal[0], state.goal[1]].astype(jnp.int32)
        at = (state.layout, jnp.maximum(slot, 0), state.pos[0], state.pos[1])
        cell = state.pos + bank.waypoint_offset[at].astype(jnp.int32)  # precomputed: one gather
        unknown = state.pos + jnp.clip(state.goal - state.pos, -k, k)
        return jnp.where(slot >= 0, cell, unknown)


# ------------------------------------------------------------------ what exports describe
def _entry(name: str, scale: float = 1.0, **more: Any) -> dict[str, Any]:
    return {"name": name, "scale": scale, "clip": None, **more}


def grid_layout(env: GridMaze, params: GridMazeParams) -> list[dict]:
    """A GridMaze observation value by value (its ``get_obs``): rows and columns are cells
    (row 0 at the top), ``blocked_*`` 1 where that move collides (an obstacle or the edge)."""
    s, mode = env.size, env.config.obs_mode
    inv = 1.0 / max(s - 1, 1)
    moves = ACTION_NAMES
    if mode == "paper":
        obstacles = params.bank.obstacle_cells.shape[1]
        entries = [_entry(n, inv) for n in ("robot_x", "robot_y", "goal_x", "goal_y")]
        for i in range(obstacles):
            entries += [_entry(f"obstacle_{axis}", inv, obstacle=i) for axis in "xy"]
        return entries
    tail = [_entry(f"blocked_{m}") for m in moves]
    tail += [_entry("goal_drow"), _entry("goal_dcol")]
    if mode == "index":
        cells = ("robot_row", "robot_col", "goal_row", "goal_col")
        return [_entry(n, categories=s) for n in cells] + tail
    if mode == "onehot":
        cells = ("robot_row", "robot_col", "goal_row", "goal_col")
        return [_entry(f"{n}_is", category=k) for n in cells for k in range(s)] + tail
    r = env.config.sensor_radius
    window = [
        _entry("occupied", offset=[dr, dc]) for dr in range(-r, r + 1) for dc in range(-r, r + 1)
    ]
    runs = [_entry(f"free_cells_{m}", inv) for m in moves]
    entries = window + runs + [_entry("goal_drow", inv), _entry("goal_dcol", inv)]
    k = env.config.waypoint_cells
    if k:  # the planner's hint: offset to the cell k moves ahead on a shortest path, / k
        entries += [_entry("waypoint_drow", 1.0 / k), _entry("waypoint_dcol", 1.0 / k)]
    return entries


GRID_QUANTITIES = {
    **{
        f"{who}_{axis}": f"the {who}'s {name} (0 at the {edge}), a category"
        for who in ("robot", "goal")
        for axis, name, edge in (("row", "row", "top"), ("col", "column", "left"))
    },
    **{
        f"{who}_{axis}_is": f"1 where the {who}'s {name} is `category`"
        for who in ("robot", "goal")
        for axis, name in (("row", "row"), ("col", "column"))
    },
    **{
        f"blocked_{m}": f"1 where moving {m} collides (an obstacle or the edge)"
        for m in ACTION_NAMES
    },
    "goal_drow": "goal row minus robot row, in cells",
    "goal_dcol": "goal column minus robot column, in cells",
    "waypoint_drow": "row of the cell `waypoint_cells` moves ahead on a shortest path to the "
    "goal (the goal once nearer), minus the robot's row",
    "waypoint_dcol": "its column minus the robot's column",
    "occupied": "1 where the cell at `offset` (drow, dcol) from the robot is an obstacle or "
    "off the grid",
    **{f"free_cells_{m}": f"free cells in a line {m} of the robot" for m in ACTION_NAMES},
    "robot_x": "the robot's column",
    "robot_y": "the robot's row",
    "goal_x": "the goal's column",
    "goal_y": "the goal's row",
    "obstacle_x": "obstacle `obstacle`'s column (the layout's, fixed)",
    "obstacle_y": "obstacle `obstacle`'s row",
}
