"""Occupancy maps (ROS map_server YAML + PGM/PNG) as robot mazes: how pixels become walls in
each mode, where the map lies in the env, its errors, and maps as one bank of layouts."""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np
import pytest
from PIL import Image

import jaxnav
from jaxnav.envs.robot import mazes as M
from jaxnav.envs.robot import occupancy as O

REPO = Path(__file__).resolve().parents[1]
FLOOR = REPO / "examples" / "maps" / "floor.yaml"
FREE, OCC, UNK = 254, 0, 205  # map_saver's shades


def write_map(
    tmp: Path,
    pixels: np.ndarray | list,
    name: str = "map",
    fmt: str = "pgm",
    resolution: float = 0.5,
    **fields: object,
) -> Path:
    """A map_server YAML and its image in ``tmp``; ``fields`` replace or add YAML entries."""
    img = np.asarray(pixels, np.uint8)
    Image.fromarray(img).save(tmp / f"{name}.{fmt}")
    doc = {
        "image": f"{name}.{fmt}",
        "resolution": resolution,
        "origin": "[0.0, 0.0, 0.0]",
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        **fields,
    }
    path = tmp / f"{name}.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in doc.items()))
    return path


def walls(path: Path, cell_size: float | None = 0.5, unknown_free: bool = False) -> np.ndarray:
    """The wall grid of a map read at one cell per pixel (0.5 m) unless told."""
    return O.load_occupancy_map(path, cell_size, unknown_free).grid


def test_trinary_map_saver_shades(tmp_path):
    path = write_map(tmp_path, [[FREE, OCC, UNK], [FREE, FREE, FREE]])
    np.testing.assert_array_equal(walls(path), [[0, 1, 1], [0, 0, 0]])
    # unexplored space is a wall unless the user asks otherwise; occupied stays a wall
    np.testing.assert_array_equal(walls(path, unknown_free=True), [[0, 1, 0], [0, 0, 0]])


def test_thresholds_are_strict(tmp_path):
    # occupied_thresh 0.6 is shade 102 exactly, free_thresh 0.2 is shade 204 exactly
    row = [101, 102, 204, 205]  # occupied, at the occupied edge, at the free edge, free
    path = write_map(tmp_path, [row, [FREE] * 4], occupied_thresh=0.6, free_thresh=0.2)
    np.testing.assert_array_equal(walls(path)[0], [1, 1, 1, 0])  # both edges are unknown
    np.testing.assert_array_equal(walls(path, unknown_free=True)[0], [1, 0, 0, 0])


def test_negate_swaps_black_and_white(tmp_path):
    path = write_map(tmp_path, [[0, 255, 0], [0, 0, 0]], negate=1)
    np.testing.assert_array_equal(walls(path), [[0, 1, 0], [0, 0, 0]])


def test_scale_mode_between_thresholds_is_free_and_transparent_unknown(tmp_path):
    grey = 150  # occupancy 0.41: between the thresholds
    rgba = [
        [[grey, grey, grey, 255], [FREE, FREE, FREE, 0], [OCC, OCC, OCC, 255]],
        [[FREE, FREE, FREE, 255]] * 3,
    ]
    scale = write_map(tmp_path, rgba, "scale", "png", mode="scale")
    np.testing.assert_array_equal(walls(scale)[0], [0, 1, 1])  # transparent: unknown, a wall
    # trinary ignores alpha; between the thresholds is unknown
    trinary = write_map(tmp_path, rgba, "trinary", "png", mode="trinary")
    np.testing.assert_array_equal(walls(trinary)[0], [1, 0, 1])


def test_raw_mode_reads_percent_and_ignores_negate(tmp_path):
    # 0 free, 50 a cost between the thresholds (free), 100 occupied, 255 unknown
    path = write_map(tmp_path, [[0, 50, 100, 255], [0] * 4], mode="raw", negate=1)
    np.testing.assert_array_equal(walls(path)[0], [0, 0, 1, 1])


def test_colour_pixels_are_averaged_to_grey(tmp_path):
    # the mean 180 is occupancy 0.29 (unknown); the red or green channel alone would be free
    path = write_map(
        tmp_path, [[[240, 240, 60], [FREE, FREE, FREE], [FREE, FREE, FREE]]], fmt="png"
    )
    np.testing.assert_array_equal(walls(path), [[1, 0, 0]])


def test_top_row_is_plus_y_and_origin_is_kept(tmp_path):
    img = np.full((4, 6), FREE, np.uint8)
    img[0, 5] = OCC  # top-right pixel
    path = write_map(tmp_path, img, origin="[-3.0, 2.5, 0.0]")
    maze = O.load_occupancy_map(path, 0.5)
    assert maze.origin == (-3.0, 2.5)
    # the occupied pixel's centre in the map frame: x = -3 + 5.5 * 0.5, y = 2.5 + 3.5 * 0.5
    x, y = maze.to_env(-3.0 + 5.5 * 0.5, 2.5 + 3.5 * 0.5)
    assert maze.cell_at(x, y) == (0, 5) and maze.grid[0, 5]
    assert maze.to_map(0.0, 0.0) == (-3.0, 2.5)  # env (0, 0): the lower-left pixel's corner


def test_resampling_is_conservative_and_keeps_lower_left(tmp_path):
    img = np.full((5, 4), FREE, np.uint8)
    img[4, 3] = OCC  # one occupied pixel in the bottom-right 2 x 2 cell
    path = write_map(tmp_path, img, resolution=0.1)
    grid = walls(path, 0.2)
    assert grid.shape == (3, 2)
    # bottom row: only the cell holding the pixel; top row: half outside the image, unknown
    np.testing.assert_array_equal(grid, [[1, 1], [0, 0], [0, 1]])
    np.testing.assert_array_equal(walls(path, 0.2, unknown_free=True), [[0, 0], [0, 0], [0, 1]])


def test_default_cell_size_is_a_whole_number_of_pixels(tmp_path):
    path = write_map(tmp_path, np.full((16, 24), FREE, np.uint8), resolution=0.05)
    maze = O.load_occupancy_map(path)
    assert maze.cell_size == pytest.approx(0.4) and maze.grid.shape == (2, 3)


@pytest.mark.parametrize(
    "key, value, what",
    [
        ("resolution", "abc", "resolution='abc': must be a finite number"),
        ("resolution", "0", "resolution=0.0: must be a positive number"),
        ("origin", "[1, 2]", "origin=[1, 2]: must be a list [x, y, yaw]"),
        ("origin", "[0, 0, 0.5]", "origin yaw=0.5: a rotated map is not supported"),
        ("negate", "2", "negate=2: must be 0 or 1"),
        ("occupied_thresh", "1.5", "occupied_thresh=1.5: must be in [0, 1]"),
        ("free_thresh", "-0.1", "free_thresh=-0.1: must be in [0, 1]"),
        ("free_thresh", "0.7", "free_thresh=0.7: must be below occupied_thresh=0.65"),
        ("mode", "fuzzy", "mode='fuzzy': must be one of trinary, scale, raw"),
        ("image", "nowhere.pgm", "nowhere.pgm: no such file"),
        ("image", "[1]", "image=[1]: must be a file name"),
    ],
)
def test_bad_field_is_one_line_naming_the_file(tmp_path, key, value, what):
    path = write_map(tmp_path, [[FREE, FREE]], **{key: value})
    with pytest.raises(M.MazeFileError) as e:
        O.load_occupancy_map(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and what in msg and "\n" not in msg


@pytest.mark.parametrize(
    "text, what",
    [
        ("image: [unclosed\n", "not valid YAML at line 2"),
        ("- a list\n", "expected a mapping of map_server fields, got list"),
        ("image: m.pgm\nresolution: 0.05\n", "missing field 'origin'"),
    ],
)
def test_bad_yaml_is_one_line_naming_the_file(tmp_path, text, what):
    path = tmp_path / "map.yaml"
    path.write_text(text)
    with pytest.raises(M.MazeFileError) as e:
        O.load_occupancy_map(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and what in msg and "\n" not in msg


def test_bad_images_are_refused_naming_the_file(tmp_path):
    path = write_map(tmp_path, [[FREE]])
    (tmp_path / "map.pgm").write_bytes(b"not an image")
    with pytest.raises(M.MazeFileError, match=r"map\.yaml: image .*cannot read it"):
        O.load_occupancy_map(path)
    # a header claiming a huge image is refused before its pixels are read
    (tmp_path / "map.pgm").write_bytes(b"P5\n100000 2\n255\n" + bytes(16))
    with pytest.raises(M.MazeFileError, match=r"map\.yaml: image .*100000 x 2 pixels"):
        O.load_occupancy_map(path)
    (tmp_path / "map.pgm").unlink()
    os.mkfifo(tmp_path / "map.pgm")  # reading a FIFO would block: refused unread
    with pytest.raises(M.MazeFileError, match=r"map\.yaml: image .*map\.pgm: not a regular"):
        O.load_occupancy_map(path)
    walled = write_map(tmp_path, [[OCC, UNK]], "walled")
    with pytest.raises(M.MazeFileError, match=r"walled\.yaml: image .*no free pixel"):
        O.load_occupancy_map(walled)
    lone = write_map(tmp_path, [[FREE, OCC, FREE]], "lone")
    with pytest.raises(M.MazeFileError, match=r"lone\.yaml: no two connected free cells"):
        O.load_occupancy_map(lone, 0.5)
    big = write_map(tmp_path, np.full((200, 200), FREE, np.uint8), "big", resolution=0.05)
    with pytest.raises(M.MazeFileError, match=r"big\.yaml: map too large: 200 x 200 cells"):
        O.load_occupancy_map(big, 0.05)
    with pytest.raises(M.MazeFileError, match=r"big\.yaml: map_cell_size=0\.12: .*whole"):
        O.load_occupancy_map(big, 0.12)


def test_example_floor_plan_resets_and_steps():
    env, params = jaxnav.make("RobotMaze-v0", maze_file=str(FLOOR), backend="kinematic")
    assert env.layout_origins == ((-6.0, -4.0),) and env.layout_names == (str(FLOOR),)
    obs, state = env.reset(jax.random.key(0), params)
    obs, state, reward, *_ = env.step(jax.random.key(1), state, 0, params)
    assert np.isfinite(np.asarray(obs)).all() and np.isfinite(float(reward))


def test_bank_of_two_map_sizes_resets_in_both(tmp_path):
    small = write_map(tmp_path, np.full((12, 16), FREE, np.uint8), "small", resolution=0.1)
    files = [str(FLOOR), str(small)]
    env, params = jaxnav.make(
        "RobotMaze-v0", maze_files=files, backend="kinematic", map_cell_size=0.4, num_goal_cells=8
    )
    assert env.num_layouts(params) == 2 and env.layout_names == tuple(files)
    grid = np.asarray(params.bank.grid[1])
    assert grid.shape == (20, 30) and grid[:17].all() and grid[:, 4:].all()  # padded top, right
    assert not grid[17:, :4].any()  # the small map's 3 x 4 cells at the lower left
    for layout in (0, 1):
        _, state = env.reset_layout(jax.random.key(layout), params, layout)
        x, y = (np.asarray(state.pose[:2]) / 0.4).astype(int)
        assert int(state.layout) == layout and not params.bank.grid[layout, 19 - y, x]


def test_maze_files_folder_and_glob(tmp_path):
    for name in ("b", "a"):
        write_map(tmp_path, [[FREE, FREE]], name)
    (tmp_path / "notes.md").write_text("not a maze")
    expected = [str(tmp_path / "a.yaml"), str(tmp_path / "b.yaml")]
    assert O.maze_file_list(str(tmp_path)) == expected
    assert O.maze_file_list(str(tmp_path / "*.yaml")) == expected
    with pytest.raises(ValueError, match=r"maze_files='.*\*\.yml': the pattern matches no file"):
        O.maze_file_list(str(tmp_path / "*.yml"))


def test_bank_refuses_mixed_cell_sizes(tmp_path):
    a = write_map(tmp_path, [[FREE, FREE]], "a", resolution=0.5)
    b = write_map(tmp_path, [[FREE, FREE]], "b", resolution=0.4)
    with pytest.raises(ValueError, match=r"b\.yaml: 0\.4 m cells, but .*a\.yaml has 0\.5 m"):
        M.pad_mazes([O.load_occupancy_map(a, None), O.load_occupancy_map(b, None)])


def test_padding_text_mazes_keeps_start_and_lower_left():
    big = M.parse_maze("cell_size: 0.5\n....\n....\n....\n", name="big")
    small = M.parse_maze("cell_size: 0.5\nS.\n.G\n", name="small")
    _, padded = M.pad_mazes([big, small])
    assert padded.grid.shape == (3, 4) and padded.start == (1, 0) and padded.goal == (2, 1)
    # the start's centre in metres is where it was: padding goes on top and to the right
    assert padded.cell_center(*padded.start) == small.cell_center(*small.start)
    np.testing.assert_array_equal(padded.grid[1:, :2], small.grid)
    assert padded.grid[0].all() and padded.grid[:, 2:].all()


def test_maze_file_and_maze_files_are_exclusive():
    with pytest.raises(ValueError, match=r"^maze_files=\('a.txt',\): give maze_file or"):
        jaxnav.make("RobotMaze-v0", maze_file="b.txt", maze_files=["a.txt"])
    with pytest.raises(ValueError, match=r"^maze_files='maps/': give a maze file exactly when"):
        jaxnav.make("RobotSimple-v0", maze_files="maps/")


def test_a_runs_inputs_include_every_maze_file_and_each_maps_image(tmp_path):
    """What a resumed run and a cached compiled program check for changes: every file of a
    bank and each map's image, so an edited image is never trained on unnoticed."""
    import shutil

    from jaxnav.config import TrainConfig
    from jaxnav.run_dir import input_checksums

    for name in ("floor.yaml", "floor.pgm"):
        shutil.copy(Path("examples/maps") / name, tmp_path / name)
    text = tmp_path / "small.txt"
    text.write_text("cell_size: 0.4\n....\n....\n")
    files = [str(tmp_path / "floor.yaml"), str(text)]
    config = TrainConfig.for_env(
        "RobotMaze-v0", env_kwargs={"maze_files": files, "backend": "kinematic"}
    )
    env = jaxnav.make(config.env, **config.env_kwargs)[0]
    image = str(tmp_path / "floor.pgm")
    assert env.config.input_files() == [files[0], image, files[1]]
    (tmp_path / "config.json").write_text("{}")
    before = input_checksums(tmp_path, config)
    assert set(before) == {"config.json", *(f"maze file {f}" for f in (*files, image))}
    (tmp_path / "floor.pgm").write_bytes((tmp_path / "floor.pgm").read_bytes()[:-1] + b"\0")
    after = input_checksums(tmp_path, config)
    assert after[f"maze file {image}"] != before[f"maze file {image}"]
