"""Maze algorithms both maze envs use (the grid and the robot's): BFS distance fields, in JAX
so that a whole bank of them is one compiled program; connected free regions
(``scipy.ndimage.label``); filling the pockets a start or goal could not leave; and the number
checks of their configs and generators.

A maze here is a bool array of cells, True for a wall (an obstacle), row 0 at the top; two
free cells are neighbours when they share a side (4-connectivity).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

UNREACHABLE = -1  # the distance of a wall or a cell cut off from the source
Cell = tuple[int, int]  # (row, col)


def is_number(v: Any) -> bool:
    """A real number (Python's or numpy's), not a bool."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def check_int(name: str, value: Any, lo: int, hi: int | None = None) -> None:
    """``ValueError`` naming ``name`` unless ``value`` is an integer (not a bool) in
    ``[lo, hi]`` (``>= lo`` without ``hi``)."""
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if hi is None:
        if not ok or value < lo:
            raise ValueError(f"{name}={value!r}: must be an integer >= {lo}")
    elif not ok or not lo <= value <= hi:
        raise ValueError(f"{name}={value!r}: must be an integer in [{lo}, {hi}]")


# Every float of an env config becomes float32 in the jitted step, where 1e39 is inf and
# sums or squares of a value much beyond this (returns over an episode, squared distances)
# overflow or lose all precision; no sane reward, speed or length comes near it
MAX_FLOAT_FIELD = 1e6
FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_fields(config: Any, bound: float = MAX_FLOAT_FIELD) -> None:
    """``ValueError`` naming the first field of the dataclass ``config`` that is annotated
    ``bool`` and holds no bool (``2`` or ``"False"``: a shape the observation space does not
    have), or annotated ``float`` (alone, or in a tuple) and holds no number in
    ``[-bound, bound]``. The configs' own checks run first and keep their messages; this one
    covers every field, including those added later. With ``bound=FLOAT32_MAX`` it refuses
    only what float32 cannot hold, for configs whose checks of derived sizes come later."""
    for f in dataclasses.fields(config):
        # annotations are strings under ``from __future__ import annotations``
        kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
        v = getattr(config, f.name)
        if kind == "bool":
            if not isinstance(v, (bool, np.bool_)):
                raise ValueError(f"{f.name}={v!r}: must be true or false")
        elif kind == "float" or (kind.startswith("tuple[float") and v is not None):
            for x in v if isinstance(v, tuple) else (v,):
                if not is_number(x) or not math.isfinite(x) or abs(x) > bound:
                    raise ValueError(
                        f"{f.name}={v!r}: must be a finite number of magnitude at most {bound:g}"
                    )


def first_blocked_cell(walls: np.ndarray, layout: Any, cells: Any) -> tuple[int, str] | None:
    """``(flat index, why)`` of the first of ``cells`` (int[..., 2] (row, col), on the host)
    that is off the grid, on a wall of its layout ``walls[layout]`` (bool[L, rows, cols];
    ``layout`` broadcasts against ``cells[..., 0]``), or whose layout is not in ``walls``;
    ``None`` when every cell is a free one."""
    cells = np.asarray(cells).reshape(-1, 2)
    layout = np.broadcast_to(np.asarray(layout), np.asarray(cells).shape[:1]).reshape(-1)
    num, rows, cols = walls.shape
    for i, ((r, c), m) in enumerate(zip(cells.tolist(), layout.tolist(), strict=True)):
        if not 0 <= m < num:
            return i, f"layout {m} is not in the bank's {num}"
        if not (0 <= r < rows and 0 <= c < cols):
            return i, f"off the {rows}x{cols} grid"
        if walls[m, r, c]:
            return i, f"a blocked cell (row {r}, col {c}) of layout {m}"
    return None


# ----------------------------------------------------------------------- distance fields
def _neighbours(x: jax.Array, fill: int) -> tuple[jax.Array, ...]:
    """Each cell's four neighbours (the last two axes), above, below, left and right; ``fill``
    beyond the grid's edge."""
    p = jnp.pad(x, [(0, 0)] * (x.ndim - 2) + [(1, 1), (1, 1)], constant_values=fill)
    return p[..., :-2, 1:-1], p[..., 2:, 1:-1], p[..., 1:-1, :-2], p[..., 1:-1, 2:]


def distance_field(walls: jax.Array, source: jax.Array) -> jax.Array:
    """BFS steps from ``source`` (row, col) to every cell; -1 for walls and unreachable."""
    h, w = walls.shape
    far = h * w
    free = jnp.logical_not(walls)
    dist = jnp.full((h, w), far, jnp.int32).at[source[0], source[1]].set(0)
    dist = jnp.where(free, dist, far)

    def relax(carry):
        d, _ = carry
        up, down, left, right = _neighbours(d, far)
        nb = jnp.minimum(jnp.minimum(up, down), jnp.minimum(left, right))
        new = jnp.where(free, jnp.minimum(d, nb + 1), far)
        return new, jnp.any(new != d)

    dist, _ = jax.lax.while_loop(lambda c: c[1], relax, (dist, jnp.asarray(True)))
    return jnp.where(dist >= far, UNREACHABLE, dist)


def shortest_path_length(walls: jax.Array, start: jax.Array, goal: jax.Array) -> jax.Array:
    """BFS length of the shortest path from ``start`` to ``goal``; -1 if there is none."""
    return distance_field(walls, goal)[start[0], start[1]]


@jax.jit
def bank_distances(walls: jax.Array, sources: jax.Array) -> jax.Array:
    """int16[B, G, h, w] BFS steps from each of ``sources[B, G, 2]`` (row, col) in its maze
    ``walls[B, h, w]``; -1 at walls and unreachable cells, everywhere for a source on a wall.

    The G searches of a maze run together, one bit each of uint32 words: a step ORs every
    cell's reached bits with its neighbours'. A cell's distance from a source counts the steps
    its bit was still clear, in bit-sliced counters (plane p holds bit p of every count), so a
    step costs a few word operations a cell rather than G distance updates (for RobotNav-v0's
    2,048 mazes x 32 goals, several times faster than ``distance_field`` per source)."""
    num, height, width = walls.shape
    num_sources = sources.shape[1]
    k = jnp.arange(num_sources)
    word, shift = k // 32, (k % 32).astype(jnp.uint32)  # source k is this bit of this word
    bit = jnp.left_shift(jnp.uint32(1), shift)
    free = jnp.where(walls, jnp.uint32(0), jnp.uint32(0xFFFFFFFF))[:, None]  # [B, 1, h, w]
    seed = jnp.zeros((num, -(-num_sources // 32), height, width), jnp.uint32)
    # distinct bits of one word: adding them is OR-ing them, repeated sources included
    seed = seed.at[jnp.arange(num)[:, None], word, sources[..., 0], sources[..., 1]].add(bit)
    planes = (height * width - 1).bit_length()  # counts up to the longest possible path

    def step(carry):
        reached, counts, _ = carry
        clear, summed = ~reached, []
        for plane in counts:  # add 1 to the count of every bit still clear
            summed.append(plane ^ clear)
            clear = plane & clear
        grown = functools.reduce(jnp.bitwise_or, _neighbours(reached, 0), reached) & free
        return grown, tuple(summed), jnp.any(grown != reached)

    reached = seed & free
    zeros = tuple(jnp.zeros_like(reached) for _ in range(planes))
    reached, counts, _ = jax.lax.while_loop(
        lambda c: c[2], step, (reached, zeros, jnp.asarray(True))
    )

    def source_bits(x: jax.Array) -> jax.Array:  # [B, words, h, w] -> 0/1 [B, G, h, w]
        return (x[:, word] >> shift[:, None, None]) & 1

    dist = sum(source_bits(c).astype(jnp.int32) << p for p, c in enumerate(counts))
    return jnp.where(source_bits(reached) == 1, dist, UNREACHABLE).astype(jnp.int16)


# ----------------------------------------------------------------------- regions
def region_labels(walls: np.ndarray) -> np.ndarray:
    """int32[..., rows, cols]: the connected free regions of each maze (the last two axes)
    numbered 1, 2, ... in reading order of their first cell, counting on through a batch of
    mazes; 0 at walls."""
    walls = np.asarray(walls, bool)
    flat = walls.reshape(-1, *walls.shape[-2:])
    structure = np.zeros((3, 3, 3), bool)  # one call for a batch: no link between mazes
    structure[1] = ndimage.generate_binary_structure(2, 1)  # 4-connectivity
    labels, _ = ndimage.label(~flat, structure)
    return labels.astype(np.int32).reshape(walls.shape)


def fill_pockets(walls: np.ndarray, ties: str = "first") -> np.ndarray:
    """Each maze (the last two axes) with every free cell outside its largest connected free
    region made a wall, so that any two free cells are joined by a path; a maze without free
    cells stays all walls. Of equally large regions the one kept is, with ``ties="first"``,
    the one whose first cell comes first in reading order, with ``"last"`` the one whose last
    cell comes first (GridMaze's layouts have always been drawn so)."""
    walls = np.asarray(walls, bool)
    labels = region_labels(walls).reshape(-1, walls.shape[-2] * walls.shape[-1])
    num = int(labels.max())
    if num == 0:
        return walls.copy()
    ids = np.arange(1, num + 1)
    count = np.bincount(labels.ravel(), minlength=num + 1)[1:]
    # labels run on through the batch: maze i holds those above the previous mazes' largest
    maze = np.searchsorted(np.maximum.accumulate(labels.max(axis=1)), ids)
    if ties == "first":
        key = ids
    elif ties == "last":
        cells = np.broadcast_to(np.arange(labels.shape[1]), labels.shape)
        key = ndimage.maximum(cells, labels, ids)
    else:
        raise ValueError(f"ties={ties!r}: must be 'first' or 'last'")
    order = np.lexsort((key, -count, maze))  # per maze: largest first, then the tie rule
    first = np.r_[True, np.diff(maze[order]) != 0]
    keep = np.zeros(len(labels), labels.dtype)
    keep[maze[order][first]] = ids[order][first]
    out = labels != keep[:, None]
    out[keep == 0] = True  # no free cell
    return out.reshape(walls.shape)


def largest_region_cell(walls: np.ndarray) -> Cell:
    """The first cell, in reading order, of the largest connected free region of ``walls``
    (of equally large ones, the one met first); ``ValueError`` if there is no free cell."""
    kept = np.argwhere(~fill_pockets(walls))
    if not len(kept):
        raise ValueError("the maze has no free cell")
    return int(kept[0, 0]), int(kept[0, 1])


def narrowest_gap(walls: np.ndarray) -> int:
    """The narrowest passage of a grid, in cells: the least, over free cells, of the shorter of
    the cell's horizontal and vertical free runs (a 1-cell corridor or door gives 1; the
    grid's edge bounds a run as a wall does). 0 for a grid with no free cell."""
    free = ~np.asarray(walls, bool)
    if not free.any():
        return 0

    def runs(rows: np.ndarray) -> np.ndarray:
        """Each free cell's run length along axis 1."""
        out = np.zeros(rows.shape, np.int64)
        for r, line in enumerate(rows):
            padded = np.concatenate([[False], line, [False]])
            edges = np.flatnonzero(padded[1:] != padded[:-1]).reshape(-1, 2)
            for start, stop in edges:
                out[r, start:stop] = stop - start
        return out

    across = np.minimum(runs(free), runs(free.T).T)
    return int(across[free].min())
