"""The maze algorithms both envs share: a bank's BFS distance tables, regions numbered in
reading order, pockets filled with either tie rule, the largest region's first cell, the
integer checks."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import bfs_distances
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxnav.envs import maze_algorithms as A


def grid(text: str) -> np.ndarray:
    return np.array([[ch == "#" for ch in row] for row in text.split()])


@settings(max_examples=25, deadline=None)
@given(
    walls=st.lists(st.booleans(), min_size=2 * 7 * 7, max_size=2 * 7 * 7),
    sources=st.lists(st.integers(0, 7 * 7 - 1), min_size=2 * 40, max_size=2 * 40),
)
def test_bank_distances_are_each_sources_bfs(walls, sources):
    # 40 sources a maze: two words of bits; repeats and sources on walls come up too
    walls = np.array(walls).reshape(2, 7, 7)
    cells = np.stack(np.divmod(np.array(sources).reshape(2, 40), 7), axis=-1).astype(np.int32)
    got = np.asarray(A.bank_distances(jnp.asarray(walls), jnp.asarray(cells)))
    assert got.shape == (2, 40, 7, 7) and got.dtype == np.int16
    for b in range(2):
        for g in range(40):
            np.testing.assert_array_equal(got[b, g], bfs_distances(walls[b], tuple(cells[b, g])))


@pytest.mark.parametrize("length", [8, 9])
def test_bank_distances_count_to_the_longest_path(length):
    # a corridor's far end is length - 1 steps away: 7 fills 3 bits of count, 8 needs a 4th
    corridor = np.zeros((1, 1, length), bool)
    got = A.bank_distances(jnp.asarray(corridor), jnp.array([[[0, 0], [0, length - 1]]]))
    np.testing.assert_array_equal(got[0, 0, 0], np.arange(length))
    np.testing.assert_array_equal(got[0, 1, 0], np.arange(length)[::-1])


# two regions of 3 cells: the left column starts first, the top row ends first
TIE = grid(".#...\n.####\n.####")


def test_regions_are_numbered_in_reading_order_and_on_through_a_batch():
    labels = A.region_labels(TIE)
    assert labels[0, 0] == 1 and labels[0, 2] == 2 and labels[2, 0] == 1 and labels[0, 1] == 0
    batch = A.region_labels(np.stack([TIE, TIE]))
    np.testing.assert_array_equal(batch[0], labels)
    np.testing.assert_array_equal(batch[1], np.where(labels, labels + 2, 0))


def test_fill_pockets_tie_rules():
    first, last = A.fill_pockets(TIE), A.fill_pockets(TIE, ties="last")
    np.testing.assert_array_equal(~first, A.region_labels(TIE) == 1)  # first cell first
    np.testing.assert_array_equal(~last, A.region_labels(TIE) == 2)  # last cell first
    with pytest.raises(ValueError, match="ties='middle'"):
        A.fill_pockets(TIE, ties="middle")


def test_fill_pockets_keeps_the_largest_region_and_all_walls():
    maze = grid("..#.\n..#.\n####")
    np.testing.assert_array_equal(A.fill_pockets(maze), grid("..##\n..##\n####"))
    walls = np.ones((2, 3), bool)
    np.testing.assert_array_equal(A.fill_pockets(walls), walls)
    with pytest.raises(ValueError, match="no free cell"):
        A.largest_region_cell(walls)
    assert A.largest_region_cell(maze) == (0, 0)
    assert A.largest_region_cell(grid("#.#.\n###.")) == (0, 3)


@settings(max_examples=40, deadline=None)
@given(
    cells=st.lists(st.booleans(), min_size=24, max_size=24),
    ties=st.sampled_from(["first", "last"]),
)
def test_filled_mazes_are_one_region_and_a_batch_is_filled_maze_by_maze(cells, ties):
    mazes = np.array(cells).reshape(2, 3, 4)
    filled = A.fill_pockets(mazes, ties)
    for maze, out in zip(mazes, filled, strict=True):
        np.testing.assert_array_equal(out, A.fill_pockets(maze, ties))
        assert (out | ~maze).all() or maze.all()  # walls stay walls
        free = np.argwhere(~out)
        if len(free):
            assert (bfs_distances(out, tuple(free[0]))[~out] >= 0).all()
            assert (~out).sum() == max(np.bincount(A.region_labels(maze).ravel())[1:])


def test_check_int():
    A.check_int("n", np.int64(3), 1, 3)
    A.check_int("n", 10**9, 0)
    for value, hi, message in [
        (0, 3, r"n=0: must be an integer in \[1, 3\]"),
        (True, None, "n=True: must be an integer >= 1"),
        (1.0, None, "n=1.0: must be an integer >= 1"),
    ]:
        with pytest.raises(ValueError, match=message):
            A.check_int("n", value, 1, hi)
