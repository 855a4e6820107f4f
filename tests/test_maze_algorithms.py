"""The maze algorithms both envs share: regions numbered in reading order, pockets filled with
either tie rule, the largest region's first cell, the integer checks."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import bfs_distances
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxnav.envs import maze_algorithms as A


def grid(text: str) -> np.ndarray:
    return np.array([[ch == "#" for ch in row] for row in text.split()])


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
