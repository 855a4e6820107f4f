"""The robot's own map: its lidar returns kept in an occupancy grid in its odometry frame, and a
shortest-path field to the goal on it, where cells no beam has ended in count as free.

This is what a map-free robot stack does with SLAM and a planner that allows unknown space: it
drives toward the goal as if the unseen were open, and a dead end it has seen becomes a wall
the plan goes around. Nothing in it comes from the maze: the grid's origin is the start pose's
position and its axes the walls' direction in the first scan (walls meeting at right angles,
as in every maze here; the start heading where the first scan holds no wall), the goal is where
its distance and bearing put it, and the cells are filled from the lidar's own ranges.

Cells (``MapState.cells``): 0 unseen, 1 a lidar return ended here, 2 the robot's centre has
been here (free whatever a return said: a return in a cell a wall only partly fills). The field
(``MapState.steps``) is kept from step to step and swept ``SWEEPS`` times a step with the
Bellman update of 4-neighbour moves (a cell: one more than its lowest neighbour), which
corrects it both ways as returns come in (cells cut off from the goal count up by one a sweep,
toward ``FAR``); a reset starts it from the Manhattan distances of an empty grid.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct

from jaxnav.envs.robot import layout

MAP_CELLS = layout.MAP_CELLS
SWEEPS = layout.MAP_SWEEPS
FAR = 2**15 - 1  # a return's cell, and cells no path reaches
ALIGN_TOLERANCE = math.radians(1.0)  # two wall segments within this are one direction


@struct.dataclass
class MapState:
    frame: jax.Array  # float32[3] the grid's origin (x, y) and axis angle in the world
    goal: jax.Array  # int32[2] the goal's cell
    cells: jax.Array  # uint8[MAP_CELLS, MAP_CELLS]: 0 unseen, 1 a return, 2 visited
    steps: jax.Array  # int16[MAP_CELLS, MAP_CELLS] moves to the goal's cell (FAR: none)


def returns(pose: jax.Array, ranges: jax.Array, angles: jax.Array, max_range: float):
    """``(points, hit)``: each beam's end in the world ([beams, 2]) and whether it met a wall
    (read less than ``max_range``)."""
    direction = pose[2] + angles
    points = pose[:2] + ranges[:, None] * jnp.stack([jnp.cos(direction), jnp.sin(direction)], -1)
    return points, ranges < max_range


def wall_angle(
    pose: jax.Array, ranges: jax.Array, angles: jax.Array, max_range: float
) -> jax.Array:
    """The walls' direction modulo 90 degrees in one scan: the segment between neighbouring
    returns whose direction (times 4, so that parallel and perpendicular walls agree) most other
    segments share, averaged over those; the heading where no two segments agree."""
    points, hit = returns(pose, ranges, angles, max_range)
    seg = jnp.roll(points, -1, axis=0) - points
    both = hit & jnp.roll(hit, -1)
    four = 4.0 * jnp.arctan2(seg[:, 1], seg[:, 0])
    agree = (jnp.cos(four[:, None] - four[None, :]) > math.cos(4 * ALIGN_TOLERANCE)) & both[None]
    votes = jnp.where(both, agree.sum(axis=1), 0)
    best = jnp.argmax(votes)
    # the circular mean of the agreeing segments, taken relative to the best one
    rel = jnp.where(agree[best], four - four[best], 0.0)
    rel = jnp.arctan2(jnp.sin(rel), jnp.cos(rel)).sum() / jnp.maximum(agree[best].sum(), 1)
    return jnp.where(votes[best] >= 2, (four[best] + rel) / 4.0, pose[2])


def cell_of(frame: jax.Array, xy: jax.Array, cell: float) -> tuple[jax.Array, jax.Array]:
    """``(index, inside)``: the (row, col) int32[..., 2] of the grid cell holding world points
    ``xy`` [..., 2] (clipped to the grid), and whether the point is on the grid."""
    d = xy - frame[:2]
    cos, sin = jnp.cos(frame[2]), jnp.sin(frame[2])
    local = jnp.stack([cos * d[..., 1] - sin * d[..., 0], cos * d[..., 0] + sin * d[..., 1]], -1)
    index = jnp.floor(local / cell + 0.5).astype(jnp.int32) + MAP_CELLS // 2
    inside = ((index >= 0) & (index < MAP_CELLS)).all(axis=-1)
    return jnp.clip(index, 0, MAP_CELLS - 1), inside


def cell_centre(frame: jax.Array, index: jax.Array, cell: float) -> jax.Array:
    """The world (x, y) of the centre of grid cell ``index`` (row, col)."""
    local = (index - MAP_CELLS // 2).astype(jnp.float32) * cell  # (along y', along x')
    cos, sin = jnp.cos(frame[2]), jnp.sin(frame[2])
    x = cos * local[1] - sin * local[0]
    y = sin * local[1] + cos * local[0]
    return frame[:2] + jnp.stack([x, y])


def observe(
    state: MapState,
    pose: jax.Array,
    ranges: jax.Array,
    angles: jax.Array,
    max_range: float,
    cell: float,
) -> MapState:
    """``state`` with one scan's returns and the robot's cell added and the field swept."""
    points, hit = returns(pose, ranges, angles, max_range)
    index, inside = cell_of(state.frame, points, cell)
    mark = (hit & inside).astype(jnp.uint8)
    cells = state.cells.at[index[:, 0], index[:, 1]].max(mark)
    robot, _ = cell_of(state.frame, pose[:2], cell)
    cells = cells.at[robot[0], robot[1]].set(2)
    return state.replace(cells=cells, steps=sweep(state.steps, cells != 1, state.goal, SWEEPS))


def sweep(steps: jax.Array, free: jax.Array, goal: jax.Array, sweeps: int) -> jax.Array:
    """``sweeps`` Bellman updates of the field ``steps`` over the ``free`` cells (the grid's
    outside counts as blocked)."""

    def once(_, d):
        p = jnp.pad(d, 1, constant_values=FAR)
        low = jnp.minimum(
            jnp.minimum(p[:-2, 1:-1], p[2:, 1:-1]), jnp.minimum(p[1:-1, :-2], p[1:-1, 2:])
        )
        d = jnp.where(free, jnp.minimum(low, FAR - 1) + 1, FAR).astype(jnp.int16)
        return d.at[goal[0], goal[1]].set(0)

    return jax.lax.fori_loop(0, sweeps, once, steps)


def start(
    pose: jax.Array,
    goal: jax.Array,
    ranges: jax.Array,
    angles: jax.Array,
    max_range: float,
    cell: float,
) -> MapState:
    """The map after the first scan at ``pose``, for the goal at world ``goal``."""
    frame = jnp.stack([pose[0], pose[1], wall_angle(pose, ranges, angles, max_range)])
    goal_cell, _ = cell_of(frame, goal, cell)
    rows = jnp.arange(MAP_CELLS)
    manhattan = jnp.abs(rows[:, None] - goal_cell[0]) + jnp.abs(rows[None, :] - goal_cell[1])
    state = MapState(
        frame=frame.astype(jnp.float32),
        goal=goal_cell,
        cells=jnp.zeros((MAP_CELLS, MAP_CELLS), jnp.uint8),
        steps=manhattan.astype(jnp.int16),
    )
    return observe(state, pose, ranges, angles, max_range, cell)
