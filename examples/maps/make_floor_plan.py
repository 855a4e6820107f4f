"""Draw the example occupancy map ``floor.pgm`` + ``floor.yaml`` as ROS map_saver writes them.

A 12 m x 8 m floor at 0.05 m a pixel (240 x 160 pixels): three rooms along the top, a hall
below split by a wall, a table and a pillar, and an unexplored patch in the top-right room.
Shades as map_saver writes them: free 254, occupied 0, unknown 205 (trinary), thresholds
0.65 / 0.196 as ROS 1's map_saver writes them. Nav2's map_saver writes free_thresh 0.25, with
which the unknown shade (occupancy (255 - 205) / 255 = 0.196) reads back as free, in Nav2's
map_server and in ``jaxnav.envs.robot.occupancy`` alike (notebooks/slam_to_policy.ipynb counts
the pixels it would open up); 0.196 keeps unknown space unknown. Everything is drawn on a 0.4 m
lattice (8 pixels), the default cell of ``jaxnav.envs.robot.occupancy``, with walls 0.1 m
thick, so the maze needs 24 wall slots at most (``RobotMaze-v0``'s default). Run from
anywhere: ``python examples/maps/make_floor_plan.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

FREE, OCCUPIED, UNKNOWN = 254, 0, 205
RESOLUTION = 0.05  # metres a pixel
CELL = 8  # pixels of the lattice the plan is drawn on (0.4 m)
COLS, ROWS = 30, 20  # lattice cells: 240 x 160 pixels
ORIGIN = (-6.0, -4.0, 0.0)  # the floor's centre at the world's (0, 0)
WALL = 2  # pixels: 0.1 m
OFFSET = 3  # an inner wall's pixels within its lattice cell

YAML = """\
image: floor.pgm
mode: trinary
resolution: {resolution:.6f}
origin: [{x:.6f}, {y:.6f}, {yaw:.6f}]
negate: 0
occupied_thresh: 0.65
free_thresh: 0.196
"""


def px(cell: int) -> int:
    return cell * CELL


def floor_plan() -> np.ndarray:
    """uint8[160, 240] pixel shades, row 0 the floor's top (+y) edge."""
    img = np.full((px(ROWS), px(COLS)), FREE, np.uint8)
    # outside the outer walls: never seen by the scanner
    edge = CELL - WALL
    img[:edge, :] = img[-edge:, :] = UNKNOWN
    img[:, :edge] = img[:, -edge:] = UNKNOWN
    img[edge:CELL, edge:-edge] = img[-CELL:-edge, edge:-edge] = OCCUPIED  # outer walls
    img[edge:-edge, edge:CELL] = img[edge:-edge, -CELL:-edge] = OCCUPIED

    def hwall(row: int, col0: int, col1: int) -> None:  # lattice cells col0..col1 inclusive
        img[px(row) + OFFSET : px(row) + OFFSET + WALL, px(col0) : px(col1 + 1)] = OCCUPIED

    def vwall(col: int, row0: int, row1: int) -> None:
        img[px(row0) : px(row1 + 1), px(col) + OFFSET : px(col) + OFFSET + WALL] = OCCUPIED

    # rooms along the top, each with a 0.8 m door onto the hall
    hwall(9, 1, 3)
    hwall(9, 6, 13)
    hwall(9, 16, 23)
    hwall(9, 26, 28)
    vwall(10, 1, 8)
    vwall(20, 1, 8)
    vwall(15, 13, 18)  # the hall's two bays
    img[px(15) : px(17), px(5) : px(7)] = OCCUPIED  # a table, 0.8 m square
    img[px(15) + 2 : px(16) - 2, px(23) + 2 : px(24) - 2] = OCCUPIED  # a pillar, 0.2 m
    img[px(2) : px(5), px(24) : px(28)] = UNKNOWN  # behind a cupboard: not yet scanned
    return img


def main() -> None:
    here = Path(__file__).resolve().parent
    Image.fromarray(floor_plan()).save(here / "floor.pgm")
    x, y, yaw = ORIGIN
    (here / "floor.yaml").write_text(YAML.format(resolution=RESOLUTION, x=x, y=y, yaw=yaw))


if __name__ == "__main__":
    main()
