"""The paper's continuous experiment (Sec. III, IV-B): a differential-drive robot in a walled
maze that sees 7 laser ranges, the goal's and its own position.

Actions (wheel speeds as (v, omega)): 0 forward (+v), 1 backward (-v), 2 turn left (+omega),
3 turn right (-omega). A control step is ``dt`` = 0.1 s; ``speed`` 2.5 m/s and ``turn_speed``
5 rad/s by default (0.25 m or 0.5 rad a step; the paper raised its robot's speed "to the maximum
possible value for quick learning").

Reward: ``goal_reward`` (+10) within ``goal_radius`` of the goal, ``collision_reward`` (-5) on
touching a wall, otherwise a step reward that falls linearly from ``step_reward_start`` (-0.5)
at the first step to ``step_reward_end`` (-1) at the time limit (the paper: "between -1 and
-0.5 depending on the current number of steps"), plus ``progress_reward`` (5) per metre the
step brought the robot closer to the goal along the maze's free cells (geodesic cell distance;
negative when it moves away). Goal and collision terminate; ``max_steps`` (250) truncates. Each
term is in ``info`` (``reward_goal``, ``reward_collision``, ``reward_step``, ``reward_progress``).
Why the progress term: with the paper's terms alone, 250 steps of -0.5..-1 cost far more than
one crash (-5), and a DQN learns to crash at once (0.5% success, 99% collisions over 3 seeds,
``benchmarks/results/robot_sweeps.md``, sweep 1); ``progress_reward=0`` restores the
paper's reward.

Observation: the last ``frames`` (4) sets, oldest first, of (7 lasers / (10 sqrt 2), goal x,
goal y, robot x, robot y) (the paper's), positions divided by the arena size, then the options:
``obs_proximity`` the distance D to the goal / (10 sqrt 2) (Table I), ``obs_goal_bearing`` the
goal's direction relative to the heading as (sin, cos), ``obs_heading`` the heading (sin, cos).
D and the bearing are on by default: with them the DQN reaches 0.96 success on RobotSimple-v0,
without them it learns far slower (``benchmarks/results/robot_sweeps.md``, sweep 3).
``PAPER_SETUP`` holds the overrides for the paper's literal speed, reward and observation.

With ``obs_absolute=False`` the frame leaves out goal (x, y) and robot (x, y), arena
coordinates a real robot has none of; D (clipped at 1) and the bearing stay, and the frame no
longer depends on the arena's size.

Lasers: by default 7 analytic ray casts over the front half (-90, -60, ..., +90 degrees from the
heading; ``geometry.laser_angles``) against the maze's wall boxes, from the robot's centre,
clipped to 10 sqrt 2 m. ``num_lasers``, ``laser_fov`` (degrees; 360 spaces the beams evenly all
around, one straight ahead) and ``laser_range`` (metres, also the normalizer) change them.

Generalist (``RobotNav-v0``, ``GENERALIST``): ``maze="families"``, a bank of 2,048 mazes from
``generators.py`` (rooms with doors, depth-first corridors 0.5 or 1 m wide, random wall
segments, pillar halls, some on a smaller sub-arena; 20 x 20 cells of 0.5 m, seed
``maze_seed``), on the ``kinematic`` backend, with 32 lasers all around (360 degrees) read to
3.5 m, ``obs_absolute=False`` and a waypoint 1 m ahead on a shortest path of 8-neighbour
moves (frame: 32 lasers, D, bearing, waypoint bearing and distance; 4 frames, 152 inputs),
moves of 0.15 m (1.5 m/s) and turns of 0.2 rad a step, -10 for a collision, -0.1..-0.2 a
step, up to -1 a step for scraping a wall (``clearance_reward`` within ``clearance`` 0.1 m of
free space), 40 wall slots (the families need at most 39 boxes; mazes that need more are
redrawn) and ``max_steps`` 800 (the longest geodesic start-goal path of 256 resets was 34.5 m,
~230 forward steps). Each setting's effect is in
``benchmarks/results/generalist_sweep_h100.md``. The geodesic table keeps ``num_goal_cells`` =
32 goal cells per maze: int16[2048, 32, 20, 20] is 50 MiB (the full all-pairs table would be
1.25 GiB and 819,200 BFS runs to build); resets draw goals from those cells only, so each maze
still offers 32 goals x every start. ``GENERALIST_SENSORS`` gives the observation's fields to
run its policy on a maze file (``RobotMaze-v0``, ``maze_file=...``, with ``num_wall_slots`` the
maze needs).

Occupancy maps (``RobotMaze-v0``, ``maze_file="floor.yaml"``): a ROS map_server YAML and its
PGM/PNG image become a maze of ``map_cell_size`` cells (``occupancy``); ``maze_files=`` takes a
list, a folder or a glob of maze files as one bank. Env coordinates are the map's minus its
origin (``RobotNav.layout_origins``, ``Maze.to_env``): the grid's lower-left corner is (0, 0).

Planner (the waypoint, and the progress reward's geodesic distance): BFS tables per maze and
goal cell (``mazes.stack_mazes``) through the cells that ``jaxnav.deploy.planner.passable``
leaves a robot of the largest radius an episode can have on that maze (``radius``, or the top
of ``radius_range`` capped at the maze's ``fit_radius``): one table serves every radius drawn
there, and a smaller robot gets a path the largest passes. The waypoint descends the tables
as ``planner.descend`` does, the deployment loop's planner (``jaxnav.deploy.navigator``). No
margin is added here: the robot stays narrower than a cell (``validate``; a drawn radius is
capped under ``HALF_CELL_FILL`` of each maze's cell), so every free cell's centre is half a
cell or more from walls and the tables are those of the free cells; a drawn radius already
keeps ``FIT_MARGIN`` at each maze's narrowest gap, and a margin measured at cell centres would
close 2-cell corridors that the robot passes with room to spare. Mazes of one bank may have
cells of different sizes (``generators``' ``jaxnav_coarse``: JaxNav's levels in their 1 m
cells beside 0.5 m families): each keeps its own, its lookahead in its own cells
(``MazeBank.waypoint_cells``), so only its coarse mazes draw robots of 0.25 m and more.

Own map (``lidar_map``, metres): the waypoint comes from a planner on a map the robot builds
from its own lidar and odometry (``lidar_map.py``: returns in a grid in the frame of the start
pose, its axes along the walls of the first scan, unseen cells free), not from the maze: a
map-free observation with the waypoint policy's layout.

JaxNav's levels (``RobotJaxNav-v0``, ``maze="jaxnav"``): the single-robot benchmark of
JaxMARL's JaxNav as SFL evaluates it, 9 x 9 interiors of 1 m cells with up to 47 random
obstacles (``jaxnav_levels.py``), with the map-free sensors (``MAPFREE_SENSORS``: the
generalist's lidar, the goal's distance and bearing, the previous action, the robot's radius, 8
frames; no waypoint); the id's settings and how its robot compares with JaxNav's are in
``registration.py``.

Backends: ``mjx`` (the default) steps the robot with MuJoCo MJX (``mjx_backend.py``: a sphere
on slide/slide/hinge joints with velocity actuators, per-env walls in the model's geom fields),
``mjx_substeps`` (2) physics steps per control step. It sees contacts at substep boundaries, so
the robot may touch a wall by up to one substep of travel (``speed * dt / mjx_substeps``, 12.5
cm by default; ``validate`` keeps it below the radius) before the episode ends. ``kinematic`` is
an exact pure-JAX unicycle that stops in front of walls (``geometry.move_with_walls``), the
fast path for quick experiments on CPU. Both share lasers, observation, reward and mazes.

Noise and randomization (for policies meant for a real robot; all off by default and in every
preset, and off means the same episodes bit for bit as without the options): laser range
noise (``laser_noise`` metres plus ``laser_noise_rel`` times the range, Gaussian, clipped to
[0, ``laser_range``]) and ``laser_dropout`` (a beam reads ``laser_range``), in the observation
only (the clearance term reads the true ranges); actuation noise (``speed_noise``,
``turn_noise``: the executed speed and turn rate are the commanded ones times 1 + N(0, std)
truncated at 3 std) and control-period jitter (``dt_jitter`` j: a step lasts dt (1 + u), u ~
U(-j, j), simulated as both speeds times 1 + u over dt, the same unicycle motion), each drawn
per step; the robot's radius, speed and turn speed per episode (``radius_range``,
``speed_range``, ``turn_speed_range``: uniform, drawn at reset and kept in the state). With
step noise on, ``stochastic_step`` is set and a step splits its key. Collision sub-steps and
the MJX substep check use the fastest possible step (``RobotConfig.max_speed``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnav import spaces
from jaxnav.deploy import planner
from jaxnav.deploy.shield import Shield
from jaxnav.environment import Environment, EnvParams, EnvState, is_concrete, layout_from_cdf
from jaxnav.envs.maze_algorithms import (
    FLOAT32_MAX,
    check_fields,
    first_blocked_cell,
    narrowest_gap,
)
from jaxnav.envs.robot import (
    generators,
    geometry,
    jaxnav_levels,
    layout,
    lidar_map,
    mazes,
    occupancy,
    shortest_paths,
)

ACTION_NAMES = ("forward", "backward", "turn_left", "turn_right")
MAZES = ("simple", "complex", "random", "file", "families", "jaxnav")
BACKENDS = ("kinematic", "mjx")
LASER_SCALE = 10.0 * math.sqrt(2.0)  # Table I: sensors normalized by their maximum variation
MAX_BANK_CELLS = 4_000_000  # random mazes are generated in Python: bounds a bank's build time
MAX_STEP_CELLS = 100  # a control step may cross at most this many cells (bounds the sub-steps)
MAX_WAYPOINT_DISTANCE = 10.0  # metres
# metres a drawn radius leaves each side of a maze's narrowest gap: with turns of 0.2 rad a
# step, a heading is off a corridor's axis by up to 0.1 rad and drifts 0.1 m in 7 steps
FIT_MARGIN = 0.1
HALF_CELL_FILL = 0.498  # a drawn radius stays under this many cells: a free cell's centre holds it
TRAIL_CELLS = layout.TRAIL_CELLS  # the trail's cells per side (in layout: the metadata has it)
MAX_WAYPOINT_CELLS = 64  # the lookahead is unrolled, one step per cell
NUM_LASERS = 7  # the paper's; RobotConfig.num_lasers' default
# the geodesic table's bytes (int16[B, goals, rows, cols]); beyond this a bank is refused, with
# a hint to keep fewer goal cells per maze (num_goal_cells)
MAX_GOAL_TABLE_BYTES = 2**30  # 1 GiB: every random bank of 10 x 10 mazes allowed today fits
_UNREACHABLE = -1e15  # where inactive wall slots go for the collision test (squares stay finite)
# RobotConfig's per-episode ranges, and the options that make a step draw random numbers
RANGE_FIELDS = ("radius_range", "speed_range", "turn_speed_range")
STEP_NOISE_FIELDS = (
    "laser_noise", "laser_noise_rel", "laser_dropout", "speed_noise", "turn_noise", "dt_jitter"
)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class RobotConfig:
    """Everything that defines a robot env; ``jaxnav.make(id, **overrides)`` replaces fields."""

    # the fields that choose the mazes (a policy tested on other mazes keeps the rest)
    MAZE_FIELDS: ClassVar[frozenset[str]] = frozenset(
        {"maze", "maze_file", "maze_seed", "num_layouts", "random_size", "num_wall_slots"}
        | {"families", "num_goal_cells", "maze_files", "map_cell_size", "unknown_free"}
    )

    maze: str = "simple"
    # maze="file": one maze file (the text format, or a map_server YAML: ``occupancy``), or
    # ``maze_files``, several as a bank: a list of files, a folder or a glob pattern. Smaller
    # mazes are padded with walls to the largest (top and right: each origin stays put)
    maze_file: str | None = None
    maze_files: str | tuple[str, ...] | None = None
    # occupancy maps only: the cell side in metres, a whole number of the map's pixels (None:
    # ``occupancy.default_cell_size``), and whether unknown pixels are free (else walls)
    map_cell_size: float | None = None
    unknown_free: bool = False
    num_layouts: int = 256  # bank size when maze == "random", "families" or "jaxnav"
    random_size: int = 10  # cells per side of random mazes (1 m cells)
    maze_seed: int = 0  # the random, families and jaxnav banks' seed (maze i depends on (seed, i))
    families: tuple[str, ...] = generators.FAMILIES  # which families, in turn, for "families"
    # goal cells per maze kept in the geodesic progress table; 0 = every cell (the paper envs).
    # The full table is 2 (rows * cols)^2 bytes a maze: 320 KB at the families' 20 x 20
    num_goal_cells: int = 0
    num_wall_slots: int = 24  # the most a maze may use; an env uses what its mazes need
    backend: str = "mjx"
    radius: float = 0.15
    speed: float = 2.5  # m/s, forward and backward
    turn_speed: float = 5.0  # rad/s
    dt: float = 0.1
    substeps: int = 4  # kinematic backend: collision sub-samples per step (raised if needed)
    mjx_substeps: int = 2  # MJX backend: physics steps per control step (dt / mjx_substeps each)
    goal_radius: float = 0.5
    max_steps: int = 250
    frames: int = 4
    num_lasers: int = NUM_LASERS
    laser_fov: float = 180.0  # degrees; 360 = all around (no duplicate back beam)
    laser_range: float = LASER_SCALE  # metres; lasers and the goal distance are divided by it
    obs_absolute: bool = True  # goal and robot (x, y) / arena in the frame (the paper's)
    obs_proximity: bool = True
    obs_heading: bool = False
    obs_goal_bearing: bool = True  # (sin, cos) of the goal's direction relative to the heading
    # metres the goal distance D is divided by (then clipped at 1); 0: ``laser_range``, so a
    # short lidar's range no longer hides how far a distant goal is
    goal_range: float = 0.0
    # the action that led to this frame, one-hot (zeros after a reset): a robot's own command
    obs_last_action: bool = False
    # the episode's robot radius in metres (clipped at 1): one policy for several robot sizes
    obs_radius: bool = False
    # an odometry trail: how many steps the robot's own path has spent in square cells of this
    # side (metres, in the frame of its start pose) at its position and at 1 and 2 cells away in
    # 8 directions around its heading; memory of where it has searched. 0: none
    trail_cell: float = 0.0
    # a collision monitor on the robot (``jaxnav.deploy.shield``): a move its lidar shows
    # blocked over the step is not executed, the robot stands that step
    shielded: bool = False
    # a global planner's hint: (sin, cos) of the direction to the point about
    # ``waypoint_distance`` metres ahead on a shortest path through the maze's free cells (that
    # many metres in whole cells, at least one), and its distance / laser_range; in metres, not
    # cells, so that the hint means the same on mazes of any cell size
    waypoint_distance: float = 0.0  # 0: no waypoint in the frame
    # the planner's moves: 4 (up, down, left, right) or 8 (also diagonal, where both cells beside
    # the diagonal are free). On 1 m cells a 4-move path's next cell flips between "up" and
    # "right" as the robot crosses a cell edge, and a greedy policy can dither there forever
    waypoint_moves: int = 8
    # > 0: the waypoint comes from the robot's own map instead of the maze (``lidar_map``: its
    # lidar returns in a grid of cells of this side, in metres, in its odometry frame, unseen
    # cells free): a map-free robot's planner. 0: from the maze's true free cells
    lidar_map: float = 0.0
    goal_reward: float = 10.0
    collision_reward: float = -5.0
    step_reward_start: float = -0.5
    step_reward_end: float = -1.0
    progress_reward: float = 5.0  # per metre of geodesic progress to the goal; 0 = the paper's
    # > 0: the progress term as potential-based shaping (Ng et al. 1999) for this discount,
    # k (d - discount d') a step and k d on reaching the goal: a search away from the goal is
    # repaid at its discounted worth. A crash keeps its potential (-k d'), so it never refunds
    # the distance still to go. 0: k (d - d') every step
    progress_discount: float = 0.0
    # per step with a wall touching the robot, falling linearly to 0 at ``clearance`` metres of
    # free space around it (the nearest laser reading less the radius); 0 = the paper's
    clearance_reward: float = 0.0
    clearance: float = 0.25
    # Sim-to-real randomization (module docstring, "Noise and randomization"); all off by
    # default and in the presets. Laser range noise: Gaussian, std ``laser_noise`` metres plus
    # ``laser_noise_rel`` times the true range; ``laser_dropout`` the chance that a beam
    # returns nothing (reads ``laser_range``). Actuation: the executed speed and turn rate are
    # the commanded ones times 1 + N(0, std) (truncated at 3 std), per step; ``dt_jitter`` j:
    # the control period is dt (1 + U(-j, j)) per step. Per episode, drawn at reset and kept in
    # the state: the robot's radius and its speed and turn speed, uniform in (low, high)
    # (None: ``radius``, ``speed``, ``turn_speed``)
    laser_noise: float = 0.0
    laser_noise_rel: float = 0.0
    laser_dropout: float = 0.0
    speed_noise: float = 0.0
    turn_noise: float = 0.0
    dt_jitter: float = 0.0
    radius_range: tuple[float, float] | None = None
    speed_range: tuple[float, float] | None = None
    turn_speed_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        # JSON (a run's config.json, --env-arg) gives ranges as lists: kept as tuples, so the
        # frozen config stays hashable and compares equal to one built in Python
        for name in (*RANGE_FIELDS, "maze_files"):
            v = getattr(self, name)
            if isinstance(v, list):
                object.__setattr__(self, name, tuple(v))

    @property
    def has_step_noise(self) -> bool:
        """Whether a step draws random numbers (laser or actuation noise, period jitter)."""
        return any(getattr(self, name) for name in STEP_NOISE_FIELDS)

    @property
    def max_speed(self) -> float:
        """The fastest the robot can move in one control step's time ``dt``, noise and jitter
        included (m/s): what the collision sub-steps and the MJX substep check must cover."""
        top = self.speed if self.speed_range is None else max(self.speed_range)
        return top * (1 + 3 * self.speed_noise) * (1 + self.dt_jitter)

    @property
    def min_radius(self) -> float:
        return self.radius if self.radius_range is None else min(self.radius_range)

    @property
    def max_radius(self) -> float:
        return self.radius if self.radius_range is None else max(self.radius_range)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field; loads and checks a maze file."""
        if self.maze not in MAZES:
            raise ValueError(f"maze={self.maze!r}: must be one of {', '.join(MAZES)}")
        if self.backend not in BACKENDS:
            raise ValueError(f"backend={self.backend!r}: must be one of {', '.join(BACKENDS)}")
        for name, lo, hi in (
            ("num_layouts", 1, 100_000),
            ("random_size", 3, 100),
            ("num_wall_slots", 4, 4096),
            ("substeps", 1, 1000),
            ("mjx_substeps", 1, 1000),
            ("max_steps", 1, 1_000_000),
            ("frames", 1, 64),
            ("num_lasers", 1, 1024),
            ("maze_seed", 0, 2**32 - 1),
            ("num_goal_cells", 0, 1_000_000),
        ):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
                raise ValueError(f"{name}={v!r}: must be an integer in [{lo}, {hi}]")
        for name in (
            "radius", "speed", "turn_speed", "dt", "goal_radius", "laser_range", "clearance"
        ):  # fmt: skip
            v = getattr(self, name)
            if not _positive(v):
                raise ValueError(f"{name}={v!r}: must be a positive number")
        if not (self.goal_range == 0 or _positive(self.goal_range)):
            raise ValueError(
                f"goal_range={self.goal_range!r}: must be a positive number of metres "
                "(0: laser_range)"
            )
        v = self.progress_discount
        if not (v == 0 or (_positive(v) and v <= 1)):
            raise ValueError(
                f"progress_discount={self.progress_discount!r}: must be a number in (0, 1] "
                "(0: the plain progress difference)"
            )
        if not (self.trail_cell == 0 or _positive(self.trail_cell)):
            raise ValueError(
                f"trail_cell={self.trail_cell!r}: must be a positive number of metres (0: no trail)"
            )
        if not (self.lidar_map == 0 or _positive(self.lidar_map)):
            raise ValueError(
                f"lidar_map={self.lidar_map!r}: must be a positive number of metres (0: the "
                "waypoint from the maze)"
            )
        if self.lidar_map and not self.waypoint_distance:
            raise ValueError(
                f"lidar_map={self.lidar_map!r}: needs a waypoint_distance (its planner gives "
                "the waypoint)"
            )
        if self.lidar_map and (self.laser_noise or self.laser_noise_rel or self.laser_dropout):
            raise ValueError(
                f"lidar_map={self.lidar_map!r}: the map reads the true ranges, so laser noise "
                "and dropout must be 0"
            )
        if type(self.waypoint_moves) is not int or self.waypoint_moves not in (4, 8):
            raise ValueError(f"waypoint_moves={self.waypoint_moves!r}: must be 4 or 8")
        w = self.waypoint_distance
        if not (w == 0 or _positive(w)) or w > MAX_WAYPOINT_DISTANCE:
            raise ValueError(
                f"waypoint_distance={w!r}: must be a number of metres in "
                f"[0, {MAX_WAYPOINT_DISTANCE:g}] (0: no waypoint)"
            )
        if not _positive(self.laser_fov) or self.laser_fov > 360:
            raise ValueError(
                f"laser_fov={self.laser_fov!r}: must be a number of degrees in (0, 360]"
            )
        generators.check_families(self.families)
        for name in (f.name for f in dataclasses.fields(self) if "reward" in f.name):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ValueError(f"{name}={v!r}: must be a finite number")
        self._validate_randomization()
        # float32 overflow first; the sane bound last, after the messages of derived sizes
        check_fields(self, bound=FLOAT32_MAX)
        travel = self.max_speed * self.dt / self.mjx_substeps
        if self.backend == "mjx" and travel >= self.min_radius:
            # contacts are seen at substep boundaries: a longer substep could carry the
            # robot's centre past a wall's face (or through a thin wall) before MJX sees it
            raise ValueError(
                f"mjx_substeps={self.mjx_substeps}: a physics substep would move the robot "
                f"{travel:g} m at speed={self.max_speed:g}, dt={self.dt:g}, not less than its "
                f"radius {self.min_radius}; use more substeps"
            )
        given = (self.maze_file is not None) + (self.maze_files is not None)
        if given > 1:
            raise ValueError(
                f"maze_files={self.maze_files!r}: give maze_file or maze_files, not both"
            )
        if (self.maze == "file") != (given == 1):
            name = "maze_files" if self.maze_files is not None else "maze_file"
            raise ValueError(
                f"{name}={getattr(self, name)!r}: give a maze file exactly when maze='file'"
            )
        if self.maze_file is not None and not isinstance(self.maze_file, (str, os.PathLike)):
            raise ValueError(f"maze_file={self.maze_file!r}: must be a path")
        if self.map_cell_size is not None and not _positive(self.map_cell_size):
            raise ValueError(
                f"map_cell_size={self.map_cell_size!r}: must be a positive number of metres"
            )
        for name in ("unknown_free", "shielded"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name}={getattr(self, name)!r}: must be true or false")
        if self.shielded and self.radius_range is not None and not self.obs_radius:
            raise ValueError(
                "shielded=True: with radius_range the monitor reads the radius from the "
                "observation; pass obs_radius=True"
            )
        if self.maze == "random" and self.num_layouts * self.random_size**2 > MAX_BANK_CELLS:
            raise ValueError(
                f"num_layouts={self.num_layouts}, random_size={self.random_size}: too many "
                f"maze cells to generate ({self.num_layouts * self.random_size**2:,}; at most "
                f"{MAX_BANK_CELLS:,})"
            )
        if self.maze in ("random", "families", "jaxnav"):
            side = {"random": self.random_size, "jaxnav": jaxnav_levels.INTERIOR}.get(
                self.maze, generators.ROWS
            )
            goals = self.num_goal_cells or None
            table = mazes.goal_table_bytes(self.num_layouts, side, side, goals)
            if table > MAX_GOAL_TABLE_BYTES:
                raise ValueError(
                    f"num_layouts={self.num_layouts}, num_goal_cells={self.num_goal_cells}: the "
                    f"geodesic progress table would take {table / 2**20:,.0f} MiB (at most "
                    f"{MAX_GOAL_TABLE_BYTES / 2**20:,.0f}); keep fewer goal cells per maze, e.g. "
                    "num_goal_cells=32, or fewer mazes"
                )
        loaded = self.load_mazes(validate_only=True)
        if self.maze == "file":
            table = mazes.goal_table_bytes(
                len(loaded), loaded[0].rows, loaded[0].cols, self.num_goal_cells or None
            )
            if table > MAX_GOAL_TABLE_BYTES:
                given = (
                    f"maze_file={self.maze_file!r}"
                    if self.maze_files is None
                    else f"maze_files={self.maze_files!r}"
                )
                raise ValueError(
                    f"{given}: {len(loaded)} maze(s) of {loaded[0].cols} x {loaded[0].rows} "
                    f"cells with num_goal_cells={self.num_goal_cells} (0: every cell) need a "
                    f"geodesic progress table of {table / 2**20:,.0f} MiB (at most "
                    f"{MAX_GOAL_TABLE_BYTES / 2**20:,.0f}); keep fewer goal cells per maze, e.g. "
                    "num_goal_cells=32, or use a larger map_cell_size"
                )
        for maze in loaded:
            mazes.check_slots(maze, self.num_wall_slots)
            width, height = maze.size_m
            if self.goal_radius >= min(width, height) / 2:
                raise ValueError(
                    f"goal_radius={self.goal_radius}: larger than the {maze.name} maze allows "
                    f"({width:g} x {height:g} m)"
                )
            if self.radius_range is None and self.radius >= maze.cell_size / 2:
                raise ValueError(
                    f"radius={self.radius}: the robot must fit in a {maze.cell_size:g} m "
                    f"cell of the {maze.name} maze (radius < {maze.cell_size / 2:g})"
                )
            if self.waypoint_distance > MAX_WAYPOINT_CELLS * maze.cell_size:
                raise ValueError(
                    f"waypoint_distance={self.waypoint_distance:g}: more than "
                    f"{MAX_WAYPOINT_CELLS} cells of the {maze.name} maze ({maze.cell_size:g} m)"
                )
            if self.max_speed * self.dt > MAX_STEP_CELLS * maze.cell_size:
                raise ValueError(
                    f"speed={self.max_speed:g}, dt={self.dt}: one control step would cross more "
                    f"than {MAX_STEP_CELLS} cells of the {maze.name} maze"
                )
        # a drawn radius is capped per maze under half its cell (``fit_radius``): the range's
        # top must fit the coarsest cells, or every maze would cap it
        coarsest = max(loaded, key=lambda m: m.cell_size)
        if self.radius_range is not None and self.max_radius >= coarsest.cell_size / 2:
            raise ValueError(
                f"radius_range={self.radius_range}: the robot must fit in a "
                f"{coarsest.cell_size:g} m cell of the {coarsest.name} maze (radius < "
                f"{coarsest.cell_size / 2:g})"
            )
        check_fields(self)

    def _validate_randomization(self) -> None:
        for name, hi in (
            ("laser_noise", math.inf),
            ("laser_noise_rel", math.inf),
            ("laser_dropout", 1.0),
            ("speed_noise", 1 / 3),  # the factor 1 + 3 std stays above 0: no reversed command
            ("turn_noise", 1 / 3),
            ("dt_jitter", 1.0),
        ):
            v = getattr(self, name)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not ok or not 0 <= v <= hi or (v == hi and name != "laser_dropout"):
                bound = "]" if name == "laser_dropout" else ")"
                upper = "inf" if hi == math.inf else f"{hi:.4g}"
                raise ValueError(f"{name}={v!r}: must be a number in [0, {upper}{bound}")
        for name in RANGE_FIELDS:
            v = getattr(self, name)
            if v is None:
                continue
            pair = isinstance(v, tuple) and len(v) == 2 and all(_positive(x) for x in v)
            if not pair or v[0] > v[1]:
                raise ValueError(
                    f"{name}={v!r}: must be a pair (low, high) of positive numbers, low <= high"
                )

    def maze_file_paths(self) -> list[str]:
        """The maze files of ``maze_file`` or ``maze_files`` (none for generated mazes)."""
        if self.maze != "file":
            return []
        if self.maze_files is None:
            return [] if self.maze_file is None else [os.fspath(self.maze_file)]
        return occupancy.maze_file_list(self.maze_files)

    def input_files(self) -> list[str]:
        """Every file the mazes are read from, a map's image included: what a cached
        program or a resumed run must find unchanged."""
        out = []
        for f in self.maze_file_paths():
            out.append(f)
            if occupancy.is_map_file(f):
                out.append(occupancy.read_map_yaml(f)["image"])
        return out

    def load_mazes(self, validate_only: bool = False) -> list[mazes.Maze]:
        if self.maze == "file":
            files = self.maze_file_paths()
            loaded = [
                occupancy.load_layout(f, self.map_cell_size, self.unknown_free) for f in files
            ]
            return mazes.pad_mazes(loaded)
        num = 1 if validate_only else self.num_layouts
        if validate_only and self.maze == "families":  # one of each: their cells may differ
            num = min(self.num_layouts, len(generators.check_families(self.families)))
        if self.maze == "random":
            return mazes.random_maze_bank(
                num,
                self.random_size,
                self.random_size,
                seed=self.maze_seed,
                num_slots=self.num_wall_slots,
            )
        if self.maze == "families":
            return generators.family_maze_bank(
                num, self.maze_seed, self.families, num_slots=self.num_wall_slots
            )
        if self.maze == "jaxnav":
            return jaxnav_levels.jaxnav_level_bank(num, self.maze_seed, self.num_wall_slots)
        return [mazes.builtin_maze(self.maze)]

    @property
    def laser_angles(self) -> jax.Array:
        """float32[num_lasers] beam directions relative to the heading (radians)."""
        return geometry.laser_angles(self.num_lasers, math.radians(self.laser_fov))


def default_config() -> RobotConfig:
    return RobotConfig()


# The paper's literal setup (its speed is not stated; "increased to the maximum possible value"),
# as overrides: ``jaxnav.make("RobotSimple-v0", **PAPER_SETUP)``. A DQN learns to end episodes by
# crashing there (benchmarks/results/robot_sweeps.md, sweep 1): why the defaults differ.
PAPER_SETUP: dict[str, Any] = {
    "speed": 1.0,
    "turn_speed": 2.0,
    "obs_proximity": False,
    "obs_goal_bearing": False,
    "progress_reward": 0.0,
}

# RobotNav-v0, the generalist: trained on many maze families, it must not rely on anything a
# real robot lacks or on one arena. See the module docstring's "Generalist" paragraph.
GENERALIST: dict[str, Any] = {
    "maze": "families",
    "backend": "kinematic",
    "num_layouts": 2048,
    "num_goal_cells": 32,
    "num_wall_slots": 40,
    "num_lasers": 32,
    "laser_fov": 360.0,
    "laser_range": 3.5,  # a small indoor lidar's; walls a step away read ~0.1, not ~0.01
    "obs_absolute": False,
    "waypoint_distance": 1.0,
    "waypoint_moves": 8,
    "turn_speed": 2.0,  # 0.2 rad a step: headings line up with 0.5 m corridors
    # 0.15 m a step: at 0.25 m (2.5 m/s) robots clipped wall corners between the beams, where a
    # 0.5 m corridor leaves 0.1 m each side (generalist_sweep rows 26 and 28)
    "speed": 1.5,
    "max_steps": 800,
    "collision_reward": -10.0,
    "step_reward_start": -0.1,
    "step_reward_end": -0.2,
    # scraping a wall costs up to 1 a step; a robot centred in a 0.5 m corridor (0.1 m each
    # side) pays nothing, so narrow corridors are not worth a crash to leave
    "clearance_reward": -1.0,
    "clearance": 0.1,
}
# The fields that shape RobotNav-v0's observation: pass them (and a num_wall_slots the maze
# needs) to run its policy elsewhere, e.g.
# ``jaxnav.make("RobotMaze-v0", maze_file=path, num_wall_slots=40, **GENERALIST_SENSORS)``
GENERALIST_SENSORS: dict[str, Any] = {
    k: GENERALIST[k]
    for k in (
        "num_lasers", "laser_fov", "laser_range", "obs_absolute", "waypoint_distance",
        "waypoint_moves",
    )  # fmt: skip
}
# The map-free observation (RobotJaxNav-v0's): the generalist's lidar, the goal's distance
# (read to 16 m) and bearing, the previous action, the robot's radius, 8 frames; no waypoint.
# Each field's effect: benchmarks/results/mapfree_sweep.md and docs/mapfree.md
MAPFREE_SENSORS: dict[str, Any] = {
    **{k: GENERALIST[k] for k in ("num_lasers", "laser_fov", "laser_range", "obs_absolute")},
    "waypoint_distance": 0.0,
    "goal_range": 16.0,
    "obs_last_action": True,
    "obs_radius": True,
    "frames": 8,
}


FAR_STEPS = jnp.iinfo(jnp.int32).max  # walls, unknown cells and the arena's outside


def descend(
    known: jax.Array,
    start: tuple[jax.Array, jax.Array],
    max_steps: int,
    moves: int,
    num_steps: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """``(row, col)`` ``num_steps`` (at most ``max_steps``; None: ``max_steps``) moves from
    cell ``start`` down the distances ``known`` (int32[rows, cols], ``FAR_STEPS`` where
    blocked), each to the lowest neighbour below the cell, the first of
    ``planner.MOVES[:moves]`` among equals; a diagonal only where both cells beside it are
    open (no cutting a corner)."""
    padded = jnp.pad(known, 1, constant_values=FAR_STEPS)  # the grid's outside
    row, col = start
    for i in range(max_steps):  # a few static steps
        # a chain of selects, not an argmin, so that XLA fuses the moves into fewer GPU
        # kernels (on a CPU too the generalist's step is faster: docs/results-history.md)
        lowest, step_row, step_col = known[row, col], 0, 0
        for d_row, d_col in planner.MOVES[:moves]:
            value = padded[row + 1 + d_row, col + 1 + d_col]
            if d_row and d_col:
                beside_free = (padded[row + 1 + d_row, col + 1] < FAR_STEPS) & (
                    padded[row + 1, col + 1 + d_col] < FAR_STEPS
                )
                value = jnp.where(beside_free, value, FAR_STEPS)
            lower = value < lowest
            lowest = jnp.where(lower, value, lowest)
            step_row = jnp.where(lower, d_row, step_row)
            step_col = jnp.where(lower, d_col, step_col)
        if num_steps is not None:  # a maze of coarser cells stops sooner
            step_row = jnp.where(i < num_steps, step_row, 0)
            step_col = jnp.where(i < num_steps, step_col, 0)
        row, col = row + step_row, col + step_col
    return row, col


def _bearing(offset: jax.Array, heading: jax.Array) -> jax.Array:
    """(sin, cos) of the direction of ``offset`` (x, y) relative to ``heading``."""
    angle = jnp.arctan2(offset[1], offset[0]) - heading
    return jnp.stack([jnp.sin(angle), jnp.cos(angle)])


def _positive(v: Any) -> bool:
    ok = isinstance(v, (int, float)) and not isinstance(v, bool)
    return ok and math.isfinite(v) and v > 0


@struct.dataclass
class RobotState(EnvState):
    pose: jax.Array  # float32[3] x, y, heading
    goal: jax.Array  # float32[2]
    layout: jax.Array  # int32 index into the maze bank
    frames: jax.Array  # float32[frames, per_frame], oldest first
    # the episode's robot where RobotConfig gives a range (drawn at reset); None: the config's
    radius: jax.Array | None = None  # float32
    speed: jax.Array | None = None  # float32
    turn_speed: jax.Array | None = None  # float32
    # with ``trail_cell``: the start pose (the odometry frame) and steps per trail cell
    origin: jax.Array | None = None  # float32[3]
    trail: jax.Array | None = None  # uint8[TRAIL_CELLS, TRAIL_CELLS]
    own_map: lidar_map.MapState | None = None  # with ``lidar_map``: the robot's own map


@struct.dataclass(kw_only=True)
class RobotParams(EnvParams):
    """The config's goal radius and reward terms (``EnvParams.from_config``) and the maze bank."""

    goal_radius: float
    goal_reward: float
    collision_reward: float
    step_reward_start: float
    step_reward_end: float
    progress_reward: float
    progress_discount: float
    clearance_reward: float
    clearance: float
    bank: mazes.MazeBank


class RobotNav(Environment[RobotState, RobotParams]):
    """Laser-based navigation of a differential-drive robot; see the module docstring."""

    family: ClassVar[str] = "robot"  # which presets train it (``jaxnav.presets``)

    stochastic_step = False  # motion is deterministic; resets draw from the key
    # a reset casts all rays anew and episodes last tens of steps: 1/16 of a batch ending
    # per step is rare (about 1/50 end per step under random actions)
    batch_reset_fraction = 1 / 16
    weighted_layouts = True  # reset_env reads params.layout_cdf

    def __init__(self, config: RobotConfig | None = None, name: str = "RobotSimple-v0"):
        """``config`` as ``jaxnav.make`` validated it (or the default one)."""
        self.config = default_config() if config is None else config
        self.name = name
        maze_list = self.config.load_mazes()
        # as many slots as the bank's largest maze needs (at most ``num_wall_slots``): every
        # slot, parked or not, costs a ray test per laser and a collision test per sub-step
        # (or an MJX geom), e.g. the simple maze needs 6 of the 24
        self.num_wall_slots = max(m.num_boxes for m in maze_list)
        # each layout's name (its file, for maze files) and map-frame origin, by bank index
        self.layout_names = tuple(m.name for m in maze_list)
        self.layout_origins = tuple(m.origin for m in maze_list)
        c = self.config
        cells = np.array([m.cell_size for m in maze_list], np.float32)
        # the largest radius that passes each maze's narrowest gap with FIT_MARGIN to spare,
        # and stays under half its cell, so that every free cell's centre holds it
        gaps = np.array([narrowest_gap(m.grid) for m in maze_list], np.float32)
        fit = np.maximum(np.minimum(gaps * cells / 2 - FIT_MARGIN, HALF_CELL_FILL * cells), 0.0)
        # the planner's tables are for the largest robot an episode can have on each maze
        # (module docstring, "Planner")
        largest = c.radius if c.radius_range is None else np.minimum(max(c.radius_range), fit)
        self.plan_radius = np.broadcast_to(np.asarray(largest, np.float64), fit.shape)
        plan_grids = np.stack(
            [
                ~planner.passable(m.grid, m.cell_size, float(r))
                for m, r in zip(maze_list, self.plan_radius, strict=True)
            ]
        )
        self._bank = mazes.stack_mazes(
            maze_list, self.num_wall_slots, c.num_goal_cells or None, plan_grids=plan_grids
        )
        # the waypoint's lookahead in whole cells of each maze (0: none)
        lookahead = [planner.waypoint_steps(c.waypoint_distance, m.cell_size) for m in maze_list]
        self._bank = self._bank.replace(
            fit_radius=jnp.asarray(fit, jnp.float32),
            waypoint_cells=jnp.asarray(lookahead, jnp.int32),
        )
        self.arena = np.asarray(self._bank.size_m, np.float32)
        # the lookahead unrolled on the mazes' tables (the bank's longest), and on the
        # observation's: the robot's own map's where it has one (0: no waypoint)
        self.maze_lookahead = max(lookahead)
        self.waypoint_steps = (
            planner.waypoint_steps(c.waypoint_distance, c.lidar_map)
            if c.lidar_map
            else self.maze_lookahead
        )
        self.angles = c.laser_angles
        # enough sub-steps that one moves less than the thinnest wall's half size
        thinnest = self._bank.walls.min_half_size()
        self.substeps = max(c.substeps, geometry.min_substeps(c.max_speed, c.dt, thinnest))
        # steps draw random numbers only with noise on: otherwise the step's key stays the
        # reset's, as before the noise options existed (the same episodes bit for bit)
        self.stochastic_step = c.has_step_noise
        self.shield = None
        if c.shielded:  # over this env's own observation (its frames, flattened)
            self.shield = Shield.from_layouts(
                layout.observation_layout(self, ACTION_NAMES),
                layout.action_layout(self, ACTION_NAMES),
                layout.sensor_layout(self),
            )
        self.physics = None
        if c.backend == "mjx":  # imported here so that `import jaxnav` does not load MuJoCo
            from jaxnav.envs.robot.mjx_backend import MjxRobot

            self.physics = MjxRobot(
                self.num_wall_slots,
                c.radius,
                tuple(self.arena),
                timestep=c.dt / c.mjx_substeps,
                substeps=c.mjx_substeps,
            )

    @property
    def default_params(self) -> RobotParams:
        return RobotParams.from_config(self.config, bank=self._bank)

    @property
    def num_actions(self) -> int:
        return len(ACTION_NAMES)

    @property
    def frame_size(self) -> int:
        c = self.config
        absolute = 4 * c.obs_absolute  # goal (x, y), robot (x, y)
        return (
            c.num_lasers + absolute + c.obs_proximity + 2 * c.obs_heading + 2 * c.obs_goal_bearing
            + 3 * (c.waypoint_distance > 0) + len(ACTION_NAMES) * c.obs_last_action
            + c.obs_radius + (1 + 2 * len(layout.TRAIL_ANGLES)) * (c.trail_cell > 0)
        )

    def observation_space(self, params: RobotParams | None = None) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (self.config.frames * self.frame_size,), jnp.float32)

    # -- episodes -----------------------------------------------------------------
    def reset_env(self, key: jax.Array, params: RobotParams) -> tuple[jax.Array, RobotState]:
        k_layout = jax.random.split(key, 4)[0]
        if params.layout_cdf is None:
            layout = jax.random.randint(k_layout, (), 0, params.bank.num_mazes)
        else:
            layout = layout_from_cdf(jax.random.uniform(k_layout), params.layout_cdf)
        return self.reset_layout(key, params, layout)

    def reset_layout(
        self, key: jax.Array, params: RobotParams, layout: jax.Array
    ) -> tuple[jax.Array, RobotState]:
        """``reset_env`` in bank maze ``layout``: start, goal and heading drawn from ``key`` as
        there (the layout's draw is left unused)."""
        bank = params.bank
        layout = jnp.asarray(layout, jnp.int32)
        _, k_start, k_goal, k_heading = jax.random.split(key, 4)
        n = bank.num_free[layout]
        if bank.goal_index is None:  # every cell can be the goal (the paper envs)
            start_idx = jax.random.randint(k_start, (), 0, n)
            goal_idx = jax.random.randint(k_goal, (), 0, n - 1)
            goal_idx = goal_idx + (goal_idx >= start_idx)  # a different cell than the start
        else:  # one of the maze's goal cells, then any other start
            k = jax.random.randint(k_goal, (), 0, bank.goal_index.shape[1])
            goal_idx = bank.goal_index[layout, k]
            start_idx = jax.random.randint(k_start, (), 0, n - 1)
            start_idx = start_idx + (start_idx >= goal_idx)
        heading = jax.random.uniform(k_heading, (), minval=-jnp.pi, maxval=jnp.pi)
        start = bank.free_xy[layout, start_idx]
        goal = bank.free_xy[layout, goal_idx]
        return self.reset_to(key, params, jnp.append(start, heading), goal, layout)

    def reset_to(
        self,
        key: jax.Array,
        params: RobotParams,
        pose: jax.Array,
        goal: jax.Array,
        layout: jax.Array | int = 0,
    ) -> tuple[jax.Array, RobotState]:
        """Start at ``pose`` (x, y, heading) with ``goal`` (x, y) in bank maze ``layout``."""
        if is_concrete(params, pose, goal, layout):  # under jit/vmap: check_reset_to first
            self.check_reset_to(params, pose, goal, layout)
        pose = jnp.asarray(pose, jnp.float32)
        goal = jnp.asarray(goal, jnp.float32)
        layout = jnp.asarray(layout, jnp.int32)
        # keys of their own (folded in), apart from the start, goal and heading draws
        robot = self._episode_robot(jax.random.fold_in(key, 2), params, layout)
        radius = robot.get("radius", self.config.radius)
        if self.config.trail_cell:
            robot["origin"] = pose
            robot["trail"] = self._visit(
                jnp.zeros((TRAIL_CELLS, TRAIL_CELLS), jnp.uint8), pose, pose
            )
        ranges = self.lasers(pose, layout, params)
        if self.config.lidar_map:
            robot["own_map"] = lidar_map.start(pose, goal, ranges, *self._map_args)
        frame = self._frame(
            pose, goal, ranges, layout, params, action=None, radius=radius,
            trail=robot.get("trail"), origin=pose, own_map=robot.get("own_map"),
        )  # fmt: skip
        frame = self._sense(frame, jax.random.fold_in(key, 1))
        frames = jnp.broadcast_to(frame, (self.config.frames, frame.shape[0]))
        state = RobotState(
            time=jnp.zeros((), jnp.int32),
            pose=pose,
            goal=goal,
            layout=layout,
            frames=frames,
            **robot,
        )
        return self.get_obs(state, params), state

    def step_env(
        self, key: jax.Array, state: RobotState, action: jax.Array, params: RobotParams
    ) -> tuple[jax.Array, RobotState, jax.Array, jax.Array, dict[str, jax.Array]]:
        c = self.config
        k_move, k_sense = jax.random.split(key) if self.stochastic_step else (key, key)
        v, omega = self._command(k_move, state, action)
        radius = c.radius if state.radius is None else state.radius
        if self.shield is not None:  # the radius the observation reads, else the config's
            scale = 1.0 if state.speed is None else state.speed / c.speed
            blocked = self.shield.blocked(self.get_obs(state, params), jnp, scale)
            v = jnp.where(blocked[action], 0.0, v)
        if self.physics is None:
            center, half_size = self._collision_boxes(params, state.layout)
            pose, collided, penetration = geometry.move_with_walls(
                state.pose, v, omega, c.dt, radius, center, half_size, True, self.substeps
            )
        else:
            walls = jax.tree.map(lambda x: x[state.layout], params.bank.walls)
            model = self.physics.with_walls(walls)
            if state.radius is not None:
                model = self.physics.with_radius(model, state.radius)
            data = self.physics.init(model, state.pose, forward=False)
            _, pose, collided, penetration = self.physics.step(model, data, v, omega)
        at_goal = jnp.linalg.norm(pose[:2] - state.goal) < params.goal_radius
        at_goal = at_goal & ~collided
        frac = state.time.astype(jnp.float32) / params.max_steps_in_episode
        step_reward = (
            params.step_reward_start + (params.step_reward_end - params.step_reward_start) * frac
        )
        r_goal = jnp.where(at_goal, params.goal_reward, 0.0)
        r_collision = jnp.where(collided, params.collision_reward, 0.0)
        r_step = jnp.where(at_goal | collided, 0.0, step_reward)
        d_before = self.goal_distance(state.pose, state.goal, state.layout, params)
        d_after = self.goal_distance(pose, state.goal, state.layout, params)
        known = (d_before >= 0) & (d_after >= 0)
        after = d_after
        if c.progress_discount:  # the goal has potential 0; a crash keeps the distance left
            after = jnp.where(at_goal, 0.0, params.progress_discount * d_after)
        r_progress = jnp.where(known, params.progress_reward * (d_before - after), 0.0)
        trail = None if state.trail is None else self._visit(state.trail, state.origin, pose)
        ranges = self.lasers(pose, state.layout, params)
        own_map = state.own_map
        if own_map is not None:
            own_map = lidar_map.observe(own_map, pose, ranges, *self._map_args)
        frame = self._frame(
            pose, state.goal, ranges, state.layout, params, action=action, radius=radius,
            trail=trail, origin=state.origin, own_map=own_map,
        )  # fmt: skip
        gap = frame[: c.num_lasers].min() * c.laser_range - radius  # free space around it
        r_clearance = params.clearance_reward * jnp.clip(1.0 - gap / params.clearance, 0.0, 1.0)
        frame = self._sense(frame, k_sense)  # the lasers as seen (the clearance read the truth)
        # drop the oldest frame, append the new one, on the flat vector: the same values in
        # a faster GPU kernel than a shift of the [frames, per_frame] array
        # (docs/results-history.md)
        flat = jnp.concatenate([state.frames.reshape(-1)[frame.shape[0] :], frame])
        frames = flat.reshape(state.frames.shape)
        state = state.replace(
            pose=pose, frames=frames, time=state.time + 1, trail=trail, own_map=own_map
        )
        info = {
            "goal_reached": at_goal,
            "collision": collided,
            "penetration": penetration,
            "reward_goal": r_goal,
            "reward_collision": r_collision,
            "reward_step": r_step,
            "reward_progress": r_progress,
            "reward_clearance": r_clearance,
        }
        reward = r_goal + r_collision + r_step + r_progress + r_clearance
        return self.get_obs(state, params), state, reward, at_goal | collided, info

    def check_reset_to(self, params: RobotParams, pose: Any, goal: Any, layout: Any = 0) -> None:
        bank = params.bank
        rows = bank.grid.shape[1]
        for name, points in (("pose", pose), ("goal", goal)):
            points = np.asarray(points, np.float64)
            xy = points[..., :2]
            # the cell holding each point, unclipped: off the arena is off the grid
            cell = np.asarray(bank.cell_size, np.float64)[np.asarray(layout)]
            with np.errstate(invalid="ignore"):
                col = np.where(np.isfinite(xy[..., 0]), np.floor(xy[..., 0] / cell), -1)
                row = np.where(np.isfinite(xy[..., 1]), rows - 1 - np.floor(xy[..., 1] / cell), -1)
            cells = np.stack([row, col], axis=-1).clip(-1, 2**31 - 1).astype(np.int64)
            bad = first_blocked_cell(np.asarray(bank.grid), layout, cells)
            if bad is not None:
                shown = points.reshape(-1, points.shape[-1])[bad[0]].tolist()
                raise ValueError(f"reset_to {name}={shown}: {bad[1]}")

    def reset_to_args(self, state: RobotState) -> tuple[jax.Array, jax.Array, jax.Array]:
        """The robot's pose, the goal and the maze, as ``reset_to`` takes them."""
        return state.pose, state.goal, state.layout

    # -- noise and randomization ------------------------------------------------------
    def _episode_robot(
        self, key: jax.Array, params: RobotParams, layout: jax.Array
    ) -> dict[str, jax.Array]:
        """The per-episode radius, speed and turn speed drawn where the config gives a range
        (``RobotState`` fields; the others are left out, None). The radius's range is capped
        at what passes the maze's narrowest gap (``fit_radius``), so no episode has a robot
        that cannot reach its goal."""
        c = self.config
        drawn = {}
        for i, name in enumerate(("radius", "speed", "turn_speed")):
            bounds = getattr(c, f"{name}_range")
            if bounds is not None:
                low, high = bounds
                if name == "radius":
                    high = jnp.minimum(high, params.bank.fit_radius[layout])
                    low = jnp.minimum(low, high)
                k = jax.random.fold_in(key, i)
                drawn[name] = jax.random.uniform(k, (), jnp.float32, low, high)
        return drawn

    def _command(
        self, key: jax.Array, state: RobotState, action: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        """``(v, omega)`` the robot executes for ``action``: the episode's speeds, times the
        actuation noise and the period's jitter where those are on."""
        c = self.config
        speed = c.speed if state.speed is None else state.speed
        turn = c.turn_speed if state.turn_speed is None else state.turn_speed
        if state.speed is None and state.turn_speed is None:
            v = jnp.array([c.speed, -c.speed, 0.0, 0.0])[action]
            omega = jnp.array([0.0, 0.0, c.turn_speed, -c.turn_speed])[action]
        else:
            s, t = jnp.asarray(speed, jnp.float32), jnp.asarray(turn, jnp.float32)
            v = jnp.stack([s, -s, 0 * s, 0 * s])[action]
            omega = jnp.stack([0 * t, 0 * t, t, -t])[action]
        if not (c.speed_noise or c.turn_noise or c.dt_jitter):
            return v, omega
        k_v, k_omega, k_dt = jax.random.split(key, 3)
        if c.speed_noise:
            v = v * (1 + c.speed_noise * jax.random.truncated_normal(k_v, -3.0, 3.0))
        if c.turn_noise:
            omega = omega * (1 + c.turn_noise * jax.random.truncated_normal(k_omega, -3.0, 3.0))
        if c.dt_jitter:
            # a period of dt (1 + u) moves the unicycle exactly as speeds times (1 + u) over dt
            # (its motion depends on v dt and omega dt only): one code path for both backends
            u = jax.random.uniform(k_dt, (), jnp.float32, -c.dt_jitter, c.dt_jitter)
            v, omega = v * (1 + u), omega * (1 + u)
        return v, omega

    def _sense(self, frame: jax.Array, key: jax.Array) -> jax.Array:
        """``frame`` with its lasers as a noisy sensor reads them (unchanged with laser noise
        and dropout off): Gaussian range noise, then dropped beams at ``laser_range``."""
        c = self.config
        if not (c.laser_noise or c.laser_noise_rel or c.laser_dropout):
            return frame
        n = c.num_lasers
        ranges = frame[:n] * c.laser_range
        k_noise, k_drop = jax.random.split(key)
        std = c.laser_noise + c.laser_noise_rel * ranges
        ranges = jnp.clip(ranges + std * jax.random.normal(k_noise, (n,)), 0.0, c.laser_range)
        if c.laser_dropout:
            dropped = jax.random.bernoulli(k_drop, c.laser_dropout, (n,))
            ranges = jnp.where(dropped, c.laser_range, ranges)
        return frame.at[:n].set(ranges / c.laser_range)

    # -- evaluation hooks -----------------------------------------------------------
    def observation_layout(self, params: RobotParams) -> dict[str, Any]:
        return layout.observation_layout(self, ACTION_NAMES)

    def action_layout(self) -> list[dict[str, Any]]:
        return layout.action_layout(self, ACTION_NAMES)

    def sensor_layout(self) -> dict[str, Any]:
        return layout.sensor_layout(self)

    def num_layouts(self, params: RobotParams) -> int:
        return params.bank.num_mazes

    def layouts_from(self, params: RobotParams, first: int) -> RobotParams:
        return params.replace(bank=jax.tree.map(lambda x: x[first:], params.bank))

    def layout_index(self, state: RobotState) -> jax.Array:
        return state.layout

    def shortest_path_length(self, state: RobotState, params: RobotParams) -> jax.Array:
        """Metres from the robot to where the episode can succeed: the any-angle shortest path
        of its centre through the maze's free cells to the goal disc (``goal_radius``), on the
        host (``shortest_paths``); -1 where there is none (or it is not positive). No episode
        without a collision reaches the disc on a shorter path, so a path ratio is at least 1."""
        bank = params.bank
        out = jax.ShapeDtypeStruct(state.layout.shape, jnp.float32)
        # unbatched arguments (the bank) get leading axes of size 1 under vmap, not copies
        return jax.pure_callback(
            shortest_paths.shortest_path_lengths,
            out,
            bank.grid,
            bank.cell_size,
            state.layout,
            state.pose[..., :2],
            state.goal,
            jnp.asarray(params.goal_radius, jnp.float32),
            vmap_method="expand_dims",
        )

    def step_length(
        self, state: RobotState, next_state: RobotState, params: RobotParams
    ) -> jax.Array:
        """Metres the robot's centre moved in the step (turns on the spot move it 0)."""
        return jnp.linalg.norm(next_state.pose[:2] - state.pose[:2])

    def sensor_ranges(self, state: RobotState, params: RobotParams) -> jax.Array:
        """The lasers' ranges in metres (``lasers``)."""
        return self.lasers(state.pose, state.layout, params)

    def scene(
        self, params: RobotParams, states: RobotState, ranges: np.ndarray
    ) -> dict[str, np.ndarray]:
        """Metres; the maze's active wall boxes (the boundary's included) as rectangles."""
        layout = int(states.layout[0])
        walls = jax.tree.map(lambda x: np.asarray(x[layout]), params.bank.walls)
        act = walls.active
        corner = walls.center[act] - walls.half_size[act]
        return {
            "xy": states.pose[:, :2],
            "heading": states.pose[:, 2],
            "lasers": ranges,
            "laser_angles": np.asarray(self.angles),
            "goal": states.goal[0],
            "walls": np.concatenate([corner, 2 * walls.half_size[act]], axis=1),
            "arena": np.asarray(self.arena, np.float32),
            "goal_radius": np.float32(params.goal_radius),
            "radius": np.float32(self.config.radius),
        }

    def _collision_boxes(
        self, params: RobotParams, layout: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        """The layout's wall boxes (centres, half sizes) for a collision test without a mask:
        inactive slots are moved 1e15 m away, beyond any disc (unmasked, the test is a little
        faster on a GPU and no slower on a CPU: docs/results-history.md)."""
        w = params.bank.walls
        # on the whole bank, so the select is not redone per env (XLA folds it when the bank
        # is a constant of the program, as in the trainer and the benchmarks)
        center = jnp.where(w.active[..., None], w.center, _UNREACHABLE)
        return center[layout], w.half_size[layout]

    # -- observation --------------------------------------------------------------
    def goal_distance(
        self, pose: jax.Array, goal: jax.Array, layout: jax.Array, params: RobotParams
    ) -> jax.Array:
        """Geodesic distance in metres from the robot's cell to the goal's cell through free
        cells (4-neighbour steps x cell size); -1 where none is known (unreachable, or, in a
        bank with K goal cells per maze, a goal that is none of them)."""
        bank = params.bank
        row, col = self._cell(pose[:2], layout, bank)
        source, known = self._goal_source(goal, layout, bank)
        # one element, not the goal's whole plane: this runs twice every step
        steps = jnp.where(known, bank.goal_distance[layout, source, row, col], -1)
        return jnp.where(steps >= 0, steps * bank.cell_size[layout], -1.0)

    @staticmethod
    def _cell(
        xy: jax.Array, layout: jax.Array, bank: mazes.MazeBank
    ) -> tuple[jax.Array, jax.Array]:
        """(row, col) of the cell of maze ``layout`` holding point ``xy`` (row 0 at the top),
        clipped to the grid."""
        rows, cols = bank.grid.shape[1:]
        cell = bank.cell_size[layout]
        col = jnp.clip(jnp.floor(xy[0] / cell), 0, cols - 1).astype(jnp.int32)
        row = rows - 1 - jnp.clip(jnp.floor(xy[1] / cell), 0, rows - 1)
        return row.astype(jnp.int32), col

    def _goal_source(
        self, goal: jax.Array, layout: jax.Array, bank: mazes.MazeBank
    ) -> tuple[jax.Array, jax.Array]:
        """``(source, known)``: the goal's row of the bank's geodesic table, and whether the
        table has one (with K goal cells per maze, a goal that is none of them has none)."""
        cols = bank.grid.shape[2]
        goal_row, goal_col = self._cell(goal, layout, bank)
        cell = goal_row * cols + goal_col
        if bank.goal_source is None:
            return cell, jnp.ones((), bool)
        source = bank.goal_source[layout, cell]
        return jnp.maximum(source, 0), source >= 0

    def _steps_to_goal(self, goal: jax.Array, layout: jax.Array, bank: mazes.MazeBank) -> jax.Array:
        """int[rows, cols] BFS steps from every cell to the goal's cell; -1 where unknown."""
        source, known = self._goal_source(goal, layout, bank)
        return jnp.where(known, bank.goal_distance[layout, source], -1)

    def waypoint(
        self, pose: jax.Array, goal: jax.Array, layout: jax.Array, params: RobotParams
    ) -> jax.Array:
        """The point ``waypoint_steps`` moves ahead of the robot's cell on a shortest path to
        the goal (``descend`` on the maze's 4-neighbour BFS distances): a cell centre, or the
        goal itself once the path reaches the goal's cell or where no path is known. The same
        descent as ``jaxnav.deploy.planner.waypoint_cell`` on the same table, in JAX."""
        bank = params.bank
        rows = bank.grid.shape[1]
        steps = self._steps_to_goal(goal, layout, bank)
        known = jnp.where(steps >= 0, steps.astype(jnp.int32), FAR_STEPS)
        start = self._cell(pose[:2], layout, bank)
        moves = self.config.waypoint_moves
        num_steps = bank.waypoint_cells[layout]
        row, col = descend(known, start, self.maze_lookahead, moves, num_steps)
        centre = jnp.stack([(col + 0.5), (rows - 0.5 - row)]).astype(jnp.float32)
        centre = centre * bank.cell_size[layout]
        use_goal = (known[row, col] == 0) | (steps[start] < 0)
        return jnp.where(use_goal, goal, centre)

    def own_waypoint(
        self, pose: jax.Array, goal: jax.Array, own_map: lidar_map.MapState
    ) -> jax.Array:
        """``waypoint`` on the robot's own map (``lidar_map``) instead of the maze's."""
        cell = self.config.lidar_map
        steps = own_map.steps.astype(jnp.int32)
        known = jnp.where(steps < lidar_map.FAR, steps, FAR_STEPS)
        start, _ = lidar_map.cell_of(own_map.frame, pose[:2], cell)
        moves = self.config.waypoint_moves
        row, col = descend(known, (start[0], start[1]), self.waypoint_steps, moves)
        centre = lidar_map.cell_centre(own_map.frame, jnp.stack([row, col]), cell)
        use_goal = (known[row, col] == 0) | (known[start[0], start[1]] == FAR_STEPS)
        return jnp.where(use_goal, goal, centre)

    def read_waypoint(
        self,
        pose: jax.Array,
        goal: jax.Array,
        layout: jax.Array,
        own_map: lidar_map.MapState | None,
        params: RobotParams,
    ) -> jax.Array:
        """The waypoint the observation holds: ``own_waypoint`` on the robot's own map where
        there is one (``lidar_map``), else ``waypoint`` on the maze's."""
        if own_map is None:
            return self.waypoint(pose, goal, layout, params)
        return self.own_waypoint(pose, goal, own_map)

    @property
    def _map_args(self) -> tuple[jax.Array, float, float]:
        """``lidar_map.start`` and ``observe``'s arguments after the ranges."""
        return self.angles, self.config.laser_range, self.config.lidar_map

    def lasers(self, pose: jax.Array, layout: jax.Array, params: RobotParams) -> jax.Array:
        """Laser ranges in metres (not normalized)."""
        # corners of the whole bank's boxes: the same every step, so XLA computes them once
        w = params.bank.walls
        lo, hi = geometry.box_bounds(w.center, w.half_size, w.active)
        ranges = geometry.lasers(pose, lo[layout], hi[layout], self.angles, self.config.laser_range)
        # materialized: fused into the frame's concatenation, the casts ran slower on a GPU
        # (docs/results-history.md)
        return jax.lax.optimization_barrier(ranges)

    def _frame(
        self,
        pose: jax.Array,
        goal: jax.Array,
        ranges: jax.Array,
        layout: jax.Array,
        params: RobotParams,
        *,
        action: jax.Array | None,
        radius: jax.Array | float,
        trail: jax.Array | None = None,
        origin: jax.Array | None = None,
        own_map: lidar_map.MapState | None = None,
    ) -> jax.Array:
        """One frame of the observation at ``pose`` with laser ``ranges`` (metres); ``action``
        led there (None: a reset); ``trail`` and ``origin`` the odometry trail with the visit at
        ``pose`` counted; ``own_map`` the robot's map with this scan in."""
        c = self.config
        parts = [ranges / c.laser_range]
        if c.obs_absolute:
            arena = jnp.asarray(self.arena)
            parts += [goal / arena, pose[:2] / arena]
        if c.obs_proximity:
            # clipped at 1 to stay in the observation space: a no-op within a 10 m square
            # arena at the default range (its diagonal), "far" beyond the range otherwise
            distance = jnp.linalg.norm(goal - pose[:2])[None] / (c.goal_range or c.laser_range)
            parts.append(jnp.minimum(distance, 1.0))
        if self.config.obs_heading:
            parts.append(jnp.stack([jnp.sin(pose[2]), jnp.cos(pose[2])]))
        if self.config.obs_goal_bearing:
            parts.append(_bearing(goal - pose[:2], pose[2]))
        if self.waypoint_steps:
            to_waypoint = self.read_waypoint(pose, goal, layout, own_map, params) - pose[:2]
            parts.append(_bearing(to_waypoint, pose[2]))
            parts.append(jnp.minimum(jnp.linalg.norm(to_waypoint) / c.laser_range, 1.0)[None])
        if c.obs_last_action:
            n = len(ACTION_NAMES)
            parts.append(jnp.zeros(n) if action is None else jax.nn.one_hot(action, n))
        if c.obs_radius:
            parts.append(jnp.minimum(jnp.asarray(radius, jnp.float32), 1.0)[None])
        if trail is not None:
            parts.append(self._trail_reading(trail, origin, pose))
        # Materialize the frame: otherwise XLA fuses the ray casts into the stacking of
        # frames and recasts them for every stacked element (half of a GPU step's time)
        return jax.lax.optimization_barrier(jnp.concatenate(parts))

    def _trail_cell(
        self, origin: jax.Array, xy: jax.Array
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """``(row, col)`` of the trail cells holding points ``xy`` ([..., 2], the maze's frame)
        in the odometry frame of the start pose ``origin``, and whether they are on the
        trail's grid (the start at the centre of cell (TRAIL_CELLS / 2, TRAIL_CELLS / 2))."""
        d = xy - origin[:2]
        cos, sin = jnp.cos(origin[2]), jnp.sin(origin[2])
        local = jnp.stack([cos * d[..., 0] + sin * d[..., 1], cos * d[..., 1] - sin * d[..., 0]])
        cell = jnp.floor(local / self.config.trail_cell + 0.5).astype(jnp.int32) + TRAIL_CELLS // 2
        inside = ((cell >= 0) & (cell < TRAIL_CELLS)).all(axis=0)
        cell = jnp.clip(cell, 0, TRAIL_CELLS - 1)
        return cell[0], cell[1], inside

    def _visit(self, trail: jax.Array, origin: jax.Array, pose: jax.Array) -> jax.Array:
        """``trail`` with one more step at ``pose`` (saturating at 255; off the grid: kept)."""
        x, y, inside = self._trail_cell(origin, pose[:2])
        count = trail[x, y]
        return trail.at[x, y].set(jnp.where(inside & (count < 255), count + 1, count))

    def _trail_reading(self, trail: jax.Array, origin: jax.Array, pose: jax.Array) -> jax.Array:
        """Steps spent at the robot's cell and 1 and 2 trail cells away in each of
        ``layout.TRAIL_ANGLES`` around the heading, each / layout.TRAIL_SATURATION clipped at 1."""
        step = self.config.trail_cell * jnp.arange(1, 3, dtype=jnp.float32)
        angles = pose[2] + jnp.asarray(layout.TRAIL_ANGLES, jnp.float32)
        ring = jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)[:, None, :] * step[None, :, None]
        points = jnp.concatenate([pose[None, :2], (pose[:2] + ring).reshape(-1, 2)])
        x, y, inside = self._trail_cell(origin, points)
        counts = jnp.where(inside, trail[x, y], 0).astype(jnp.float32)
        return jnp.minimum(counts / layout.TRAIL_SATURATION, 1.0)

    def get_obs(self, state: RobotState, params: RobotParams) -> jax.Array:
        return state.frames.reshape(-1)
