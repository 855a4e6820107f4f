"""Occupancy maps saved by ROS map_server / map_saver (slam_toolbox, gmapping, cartographer) as
robot mazes: a YAML file beside a PGM or PNG image, read into a ``mazes.Maze``.

The YAML fields, as map_server reads them (all required but ``mode``)::

    image: floor.pgm          # relative to the YAML file's folder
    resolution: 0.05          # metres per pixel
    origin: [-2.0, -1.5, 0.0] # world pose (x, y, yaw) of the image's lower-left pixel
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.196
    mode: trinary             # trinary (default), scale or raw

Pixels, as map_server (ROS 2, Nav2's map_io) classifies them: a colour pixel's shade p is the
mean of its colour channels (an alpha channel left out); occupancy is (255 - p) / 255, or p / 255
with ``negate: 1``. Then per ``mode``:

- ``trinary``: occupancy > occupied_thresh is occupied, < free_thresh free (both strict, so a
  pixel exactly at a threshold is unknown), anything between unknown; alpha is ignored.
- ``scale``: a pixel not fully opaque (alpha < 255) is unknown; otherwise as trinary, except that
  a value between the thresholds is a known, partly occupied cell: free here (map_server scales
  it to 1..99, a cost that is no obstacle).
- ``raw``: the shade p itself (``negate`` ignored, as map_server does) is the cell value: 0..100
  an occupancy percent, classified by the thresholds as in scale mode (p / 100 against them),
  above 100 unknown; alpha is ignored.

A cell of the maze is a wall or free: occupied pixels are walls, and so are unknown ones unless
``unknown_free`` (an unexplored area is no place to drive). Image row 0 is the map's top (+y)
edge. Resampling to ``cell_size`` metres (a whole number k of pixels) is conservative: a cell
is a wall where any of its k x k pixels is occupied (or unknown); a partial cell beyond the
image's top or right edge counts the missing pixels as unknown.

Coordinates: the maze keeps the map's ``origin`` (x, y) as ``Maze.origin``; the env's
coordinates (poses, goals, ``reset_to``, rendering) put (0, 0) at the lower-left corner of the
grid, which is the image's lower-left pixel, so env = map - origin (``Maze.to_env``) and map =
env + origin (``Maze.to_map``). A non-zero yaw is refused, as Nav2 refuses it.
"""

from __future__ import annotations

import functools
import glob
import math
import os
import stat
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from jaxnav.deploy.planner import GridMap
from jaxnav.envs.robot.mazes import CELL_SIZE_RANGE, Maze, MazeFileError, load_maze

MODES = ("trinary", "scale", "raw")
SUFFIXES = (".yaml", ".yml")
MAX_YAML_BYTES = 100_000
MAX_IMAGE_SIDE = 8_192  # pixels (410 m at 0.05 m); checked from the header, before decoding
# The maze's cells: the geodesic table is 2 (rows * cols)^2 bytes a map (512 MiB here)
MAX_MAP_CELLS = 16_384
# The default cell: the smallest whole number of pixels at least this wide (a 0.15 m robot
# fits, radius < cell / 2), grown until the grid has at most DEFAULT_MAX_CELLS cells
DEFAULT_CELL_SIZE = 0.4
DEFAULT_MAX_CELLS = 4_096  # 64 x 64: a 32 MiB geodesic table
# map_cell_size must be this close to a whole number of pixels (relative)
MULTIPLE_TOLERANCE = 1e-6


def is_map_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names a map_server YAML file (by its suffix) rather than a text maze."""
    return Path(path).suffix.lower() in SUFFIXES


@functools.lru_cache(maxsize=64)  # maps are immutable; a changed file has another key
def _cached(
    name: str,
    stamps: tuple[Any, ...],
    fields: tuple[tuple[str, Any], ...],
    cell_size: float | None,
    unknown_free: bool,
) -> Maze:
    return _read_map(name, dict(fields), cell_size, unknown_free)


def load_occupancy_map(
    path: str | os.PathLike[str], cell_size: float | None = None, unknown_free: bool = False
) -> Maze:
    """The maze of a map_server YAML file (module docstring). ``cell_size`` None: the default
    (``default_cell_size``). ``MazeFileError`` (a ``ValueError``) ``"path: what is wrong"`` for
    a malformed YAML field, a missing or unreadable image, or a map too large or with no free
    cell. An unchanged YAML and image (size, modification time) are not read again."""
    name = os.fspath(path)
    if cell_size is not None and (
        isinstance(cell_size, bool) or not isinstance(cell_size, (int, float))
    ):
        raise MazeFileError(name, f"map_cell_size={cell_size!r}: must be a number of metres")
    fields = read_map_yaml(name)
    stamps = (_stamp(name), _stamp(fields["image"]))
    return _cached(name, stamps, tuple(sorted(fields.items())), cell_size, bool(unknown_free))


def _stamp(name: str) -> tuple[int, int, int, int] | None:
    try:
        info = os.stat(name)
    except OSError:
        return None  # reading it says why
    return info.st_dev, info.st_ino, info.st_mtime_ns, info.st_size


def _check_not_special(path: str, name: str, what: str) -> None:
    """``MazeFileError`` for a FIFO, socket or device: reading one blocks or never ends."""
    try:
        mode = os.stat(name).st_mode
    except OSError:
        return  # reading it says why
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise MazeFileError(path, f"{what}{name}: not a regular file")


def read_map_yaml(path: str) -> dict[str, Any]:
    """The checked fields of a map_server YAML file: ``image`` (resolved beside the YAML),
    ``resolution``, ``origin`` (x, y), ``negate`` (bool), the thresholds and ``mode``."""

    def fail(what: str) -> MazeFileError:
        return MazeFileError(path, what)

    _check_not_special(path, path, "")
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_YAML_BYTES + 1)  # bounded: /dev/zero is not a map
    except OSError as e:
        raise fail(f"cannot read the map file: {e.strerror or e}") from e
    if len(data) > MAX_YAML_BYTES:
        raise fail(f"larger than {MAX_YAML_BYTES:,} bytes: not a map_server YAML file")
    try:
        doc = yaml.safe_load(data)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or "invalid YAML"
        raise fail(f"not valid YAML{where}: {problem}") from None
    if not isinstance(doc, dict):
        raise fail(f"expected a mapping of map_server fields, got {type(doc).__name__}")
    for key in ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"):
        if key not in doc:
            raise fail(f"missing field {key!r}")

    image = doc["image"]
    if not isinstance(image, str) or not image.strip():
        raise fail(f"image={image!r}: must be a file name")
    resolution = _number(fail, "resolution", doc["resolution"])
    if not resolution > 0:
        raise fail(f"resolution={resolution!r}: must be a positive number of metres per pixel")
    origin = doc["origin"]
    if not isinstance(origin, list) or len(origin) != 3:
        raise fail(f"origin={origin!r}: must be a list [x, y, yaw]")
    x, y, yaw = (_number(fail, f"origin[{i}]", v) for i, v in enumerate(origin))
    if yaw != 0:
        raise fail(f"origin yaw={yaw!r}: a rotated map is not supported (as in Nav2); use 0")
    negate = doc["negate"]
    if negate not in (0, 1) or isinstance(negate, float):
        raise fail(f"negate={negate!r}: must be 0 or 1")
    occupied = _number(fail, "occupied_thresh", doc["occupied_thresh"])
    free = _number(fail, "free_thresh", doc["free_thresh"])
    for key, v in (("occupied_thresh", occupied), ("free_thresh", free)):
        if not 0 <= v <= 1:
            raise fail(f"{key}={v!r}: must be in [0, 1]")
    if free >= occupied:
        raise fail(f"free_thresh={free!r}: must be below occupied_thresh={occupied!r}")
    mode = doc.get("mode", "trinary")
    if mode not in MODES:
        raise fail(f"mode={mode!r}: must be one of {', '.join(MODES)}")
    return {
        "image": os.path.join(os.path.dirname(path), image),
        "resolution": resolution,
        "origin": (x, y),
        "negate": bool(negate),
        "occupied_thresh": occupied,
        "free_thresh": free,
        "mode": mode,
    }


def _number(fail: Any, key: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise fail(f"{key}={v!r}: must be a finite number")
    return float(v)


def occupancy_classes(
    pixels: np.ndarray, mode: str, negate: bool, occupied_thresh: float, free_thresh: float
) -> tuple[np.ndarray, np.ndarray]:
    """(occupied, unknown) bool[H, W] of uint8 pixels[H, W, C] (C = 1 grey, 2 grey + alpha,
    3 RGB, 4 RGBA) as map_server classifies them (module docstring); the rest is free."""
    channels = pixels.shape[-1]
    has_alpha = channels in (2, 4)
    colour = pixels[..., : channels - 1] if has_alpha else pixels
    # classes of every possible channel sum, looked up per pixel: exact and light on memory
    sums = colour.sum(axis=-1, dtype=np.uint16)
    n = colour.shape[-1]
    occupied, unknown = _classes_of_shades(
        np.arange(255 * n + 1) / n, mode, negate, occupied_thresh, free_thresh
    )
    occupied, unknown = occupied[sums], unknown[sums]
    if mode == "scale" and has_alpha:  # not fully opaque: unknown
        unknown = unknown | (pixels[..., -1] != 255)
        occupied = occupied & ~unknown
    return occupied, unknown


def _classes_of_shades(
    shade: np.ndarray, mode: str, negate: bool, occupied_thresh: float, free_thresh: float
) -> tuple[np.ndarray, np.ndarray]:
    if mode == "raw":
        value = np.rint(shade)
        known = value <= 100
        occ = np.where(known, value / 100.0, 0.0)
    else:
        occ = (shade if negate else 255.0 - shade) / 255.0
        known = np.ones(shade.shape, bool)
    occupied = known & (occ > occupied_thresh)
    free = known & (occ < free_thresh)
    if mode in ("scale", "raw"):  # a known value between the thresholds is a cost, no obstacle
        free = known & ~occupied
    return occupied, ~occupied & ~free


def default_cell_size(resolution: float, width: int, height: int) -> float:
    """The default cell of a ``width`` x ``height`` pixel map: the smallest whole number of
    pixels at least ``DEFAULT_CELL_SIZE`` wide that keeps the grid within
    ``DEFAULT_MAX_CELLS`` cells."""
    k = max(1, math.ceil(DEFAULT_CELL_SIZE / resolution - MULTIPLE_TOLERANCE))
    while math.ceil(width / k) * math.ceil(height / k) > DEFAULT_MAX_CELLS:
        k += 1
    return round(k * resolution, 9)


def _read_map(path: str, f: dict[str, Any], cell_size: float | None, unknown_free: bool) -> Maze:
    def fail(what: str) -> MazeFileError:
        return MazeFileError(path, what)

    res, image = f["resolution"], f["image"]
    _check_not_special(path, image, "image ")
    try:
        with Image.open(image) as im:
            width, height = im.size  # the header only: sizes are checked before decoding
            if max(width, height) > MAX_IMAGE_SIDE:
                raise fail(
                    f"image {image}: {width} x {height} pixels, more than {MAX_IMAGE_SIDE} a side"
                )
            k = _pixels_per_cell(fail, res, width, height, cell_size)
            rows, cols = math.ceil(height / k), math.ceil(width / k)
            if rows * cols > MAX_MAP_CELLS:
                raise fail(
                    f"map too large: {rows} x {cols} cells of {k * res:g} m (at most "
                    f"{MAX_MAP_CELLS:,} cells); use a larger map_cell_size"
                )
            pixels = _pixel_array(im)
    except MazeFileError:
        raise
    except FileNotFoundError:
        raise fail(f"image {image}: no such file") from None
    except (OSError, UnidentifiedImageError, Image.DecompressionBombError, ValueError) as e:
        raise fail(f"image {image}: cannot read it as a PGM or PNG image ({e})") from None
    occupied, unknown = occupancy_classes(
        pixels, f["mode"], f["negate"], f["occupied_thresh"], f["free_thresh"]
    )
    if not (~occupied & ~unknown).any():
        raise fail(f"image {image}: no free pixel (mode {f['mode']}, negate {int(f['negate'])})")
    blocked = occupied | (unknown & (not unknown_free))
    grid = resample(blocked, k, pad=not unknown_free)
    if grid.all():
        raise fail(
            f"no free cell at {k * res:g} m cells: every cell holds a wall pixel; "
            "use a smaller map_cell_size"
        )
    size = round(k * res, 9) if cell_size is None else float(cell_size)
    maze = Maze(grid, size, name=path, origin=f["origin"], kind="occupancy map")
    if len(maze.placement_cells()) < 2:
        raise fail(
            f"no two connected free cells at {size:g} m cells; a start and a goal need a path "
            "(use a smaller map_cell_size)"
        )
    return maze


def _pixels_per_cell(
    fail: Any, resolution: float, width: int, height: int, cell_size: float | None
) -> int:
    if cell_size is None:
        size = default_cell_size(resolution, width, height)
        return max(1, round(size / resolution))
    lo, hi = CELL_SIZE_RANGE
    if not math.isfinite(cell_size) or not lo <= cell_size <= hi:
        raise fail(f"map_cell_size={cell_size!r}: must be in [{lo:g}, {hi:g}] metres")
    k = round(cell_size / resolution)
    if k < 1 or abs(k * resolution - cell_size) > MULTIPLE_TOLERANCE * cell_size:
        raise fail(
            f"map_cell_size={cell_size!r}: must be a whole number of {resolution:g} m pixels"
        )
    return k


def _pixel_array(im: Image.Image) -> np.ndarray:
    """uint8[H, W, C] of a grey, grey + alpha, RGB or RGBA image (16-bit greys scaled down)."""
    if im.mode in ("I", "I;16", "I;16B", "I;16L"):  # 16-bit PGM: map_server reads 8 bits
        return (
            (np.asarray(im, dtype=np.float64) / 257.0)
            .round()
            .clip(0, 255)
            .astype(np.uint8)[..., None]
        )
    if im.mode not in ("L", "LA", "RGB", "RGBA"):
        im = im.convert("RGBA" if "A" in im.mode or "transparency" in im.info else "RGB")
    a = np.asarray(im, dtype=np.uint8)
    return a[..., None] if a.ndim == 2 else a


def resample(blocked: np.ndarray, k: int, pad: bool = True) -> np.ndarray:
    """bool[ceil(H / k), ceil(W / k)]: a cell is True where any of its k x k pixels of
    bool ``blocked[H, W]`` is. The grid's lower-left cell starts at the image's lower-left
    pixel, so a partial cell lies along the top or right edge; its missing pixels count as
    ``pad``."""
    h, w = blocked.shape
    rows, cols = -(-h // k), -(-w // k)
    full = np.full((rows * k, cols * k), pad, bool)
    full[rows * k - h :, :w] = blocked  # the image's bottom row on the grid's bottom row
    return full.reshape(rows, k, cols, k).any(axis=(1, 3))


# ------------------------------------------------------------------------- maze files
LAYOUT_SUFFIXES = (".txt", *SUFFIXES)  # what a folder of maze_files contributes
GLOB_CHARS = "*?["


def load_layout(
    path: str | os.PathLike[str], cell_size: float | None = None, unknown_free: bool = False
) -> Maze:
    """A maze file of either format: a map_server YAML (by its suffix, ``load_occupancy_map``
    with ``cell_size`` and ``unknown_free``) or the text format (``mazes.load_maze``; its own
    ``cell_size`` header)."""
    if is_map_file(path):
        return load_occupancy_map(path, cell_size, unknown_free)
    return load_maze(path)


def load_grid_map(
    path: str | os.PathLike[str], cell_size: float | None = None, unknown_free: bool = False
) -> GridMap:
    """``load_layout``'s maze as the deployment planner's map (``jaxnav.deploy.planner``):
    the same grid, cell size and map-frame origin the simulator reads from the file."""
    maze = load_layout(path, cell_size, unknown_free)
    return GridMap(maze.grid, maze.cell_size, maze.origin)


def maze_file_list(spec: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]) -> list[str]:
    """The files of ``maze_files``: a list of files, a folder (its ``.txt``, ``.yaml`` and
    ``.yml`` files, sorted) or a glob pattern (its matches, sorted); ``ValueError`` naming the
    spec when it gives no file."""
    if isinstance(spec, (str, os.PathLike)):
        name = os.fspath(spec)
        if os.path.isdir(name):
            files = sorted(
                os.path.join(name, f)
                for f in os.listdir(name)
                if Path(f).suffix.lower() in LAYOUT_SUFFIXES
                and os.path.isfile(os.path.join(name, f))
            )
            what = f"no maze file ({', '.join(LAYOUT_SUFFIXES)}) in the folder"
        elif any(ch in name for ch in GLOB_CHARS):
            files = sorted(f for f in glob.glob(name) if os.path.isfile(f))
            what = "the pattern matches no file"
        else:
            files, what = [name], ""
        if not files:
            raise ValueError(f"maze_files={name!r}: {what}")
        return files
    if not isinstance(spec, (list, tuple)) or not all(
        isinstance(f, (str, os.PathLike)) for f in spec
    ):
        raise ValueError(f"maze_files={spec!r}: must be a list of paths, a folder or a pattern")
    if len(spec) == 0:
        raise ValueError("maze_files=[]: give at least one maze file")
    return [os.fspath(f) for f in spec]
