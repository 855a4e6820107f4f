"""The MJX robot backend (jaxnav/envs/robot/mjx_backend.py) against the kinematic geometry.

Compiled functions are module-scoped fixtures: one jitted single-env step and init, one
jitted vmapped step and init over 8 envs; each test only pays for its rollouts.
"""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxnav.envs.robot import geometry as g
from jaxnav.envs.robot import mazes
from jaxnav.envs.robot.mjx_backend import MAX_GEOM_PAIRS, MjxRobot, build_model

SLOTS = 24
RADIUS = 0.15
ARENA = (10.0, 10.0)
DT = 0.1
# Measured on this CPU (float32): free-space pose error after 50 mixed steps ~6e-6 m and
# ~1e-6 rad (deadbeat gains plus the mid-substep heading follow the exact arc); bounds leave
# two orders of magnitude for other platforms.
FREE_POS_TOL = 1e-3
FREE_YAW_TOL = 1e-3
# Measured: up to 10-13 mm over the substeps on impact at 0.5-2 m/s, 1-5 mm at rest against
# the wall (the actuator pushes into a soft contact).
MAX_PENETRATION = 0.03
# Contact dist of a state vs circle_box_penetration at the same pose: equal to ~1e-7 m.
CONTACT_VS_ANALYTIC = 1e-4


@pytest.fixture(scope="module")
def robot() -> MjxRobot:
    return MjxRobot(SLOTS, RADIUS, ARENA)


@pytest.fixture(scope="module")
def step(robot):
    return jax.jit(robot.step)


@pytest.fixture(scope="module")
def init(robot):
    return jax.jit(robot.init)


@pytest.fixture(scope="module")
def simple_walls() -> mazes.Walls:
    return mazes.builtin_maze("simple").walls(SLOTS)


def test_build_model_settings():
    m = build_model(SLOTS, RADIUS, ARENA, timestep=0.02, substeps=5)
    assert m.ngeom == SLOTS + 1 and m.nmat >= 1  # a material: mjx.ray needs one
    assert m.opt.timestep == pytest.approx(0.02)
    assert m.opt.iterations == 1 and m.opt.ls_iterations == 4
    assert m.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON
    assert (m.geom_condim == 1).all()
    nid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_NUMERIC, "max_geom_pairs")
    assert m.numeric_data[m.numeric_adr[nid]] == MAX_GEOM_PAIRS == 8
    robot_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "robot")
    assert m.geom_type[robot_geom] == mujoco.mjtGeom.mjGEOM_SPHERE
    assert m.geom_size[robot_geom, 0] == pytest.approx(RADIUS)
    walls = [i for i in range(m.ngeom) if i != robot_geom]
    assert (m.geom_type[walls] == mujoco.mjtGeom.mjGEOM_BOX).all()
    assert (np.abs(m.geom_pos[walls, :2]) > 100).all()  # parked far outside the arena
    assert m.nu == 3 and m.njnt == 3
    with pytest.raises(ValueError):
        build_model(0, RADIUS, ARENA, 0.02, 5)


def test_with_walls_parks_inactive_slots(robot, simple_walls):
    inside = simple_walls.replace(center=simple_walls.center.at[-1].set(jnp.array([5.0, 5.0])))
    model = robot.with_walls(inside)
    w = robot.wall_geoms
    active = np.asarray(inside.active)
    np.testing.assert_allclose(model.geom_pos[w[active], :2], simple_walls.center[active])
    np.testing.assert_allclose(model.geom_size[w[active], :2], simple_walls.half_size[active])
    assert (np.asarray(model.geom_pos[w[~active], :2]) == mazes.PARKED_CENTER).all()
    np.testing.assert_allclose(
        model.geom_rbound[w], np.linalg.norm(np.asarray(model.geom_size[w]), axis=-1), rtol=1e-6
    )


def test_free_space_matches_unicycle(robot, step, init):
    rng = np.random.default_rng(0)
    start = jnp.array([5.0, 5.0, 0.3])
    data = init(robot.model, start)  # every wall parked: free space
    ref = start
    pos_err, yaw_err = [], []
    for k in range(50):
        # mixed: straight, turning in place, arcs, reversing
        v = [0.8, 0.0, rng.uniform(-1, 1)][k % 3]
        omega = [0.0, 1.5, rng.uniform(-2, 2)][k % 3]
        data, pose, collided, pen = step(robot.model, data, v, omega)
        ref = g.unicycle_step(ref, v, omega, DT)
        assert not collided and pen == 0.0
        pos_err.append(float(jnp.linalg.norm(pose[:2] - ref[:2])))
        yaw_err.append(abs(float(g.wrap_angle(pose[2] - ref[2]))))
        assert -math.pi < float(pose[2]) <= math.pi
    assert max(pos_err) < FREE_POS_TOL, max(pos_err)
    assert max(yaw_err) < FREE_YAW_TOL, max(yaw_err)


def test_turn_in_place_and_forward(robot, step, init):
    data = init(robot.model, jnp.array([5.0, 5.0, 3.0]))
    for _ in range(10):  # 1.5 rad/s for 1 s: crosses +pi, so the wrap is exercised
        data, pose, _, _ = step(robot.model, data, 0.0, 1.5)
    np.testing.assert_allclose(pose[:2], [5.0, 5.0], atol=1e-4)
    assert abs(float(g.wrap_angle(pose[2] - (3.0 + 1.5)))) < FREE_YAW_TOL
    assert -math.pi < float(pose[2]) <= math.pi

    heading = 0.7
    data = init(robot.model, jnp.array([5.0, 5.0, heading]))
    for _ in range(10):
        data, pose, _, _ = step(robot.model, data, 0.8, 0.0)
    moved = np.asarray(pose[:2]) - 5.0
    along = moved @ np.array([math.cos(heading), math.sin(heading)])
    across = moved @ np.array([-math.sin(heading), math.cos(heading)])
    assert along == pytest.approx(0.8, abs=1e-3) and abs(across) < 1e-4
    assert float(pose[2]) == pytest.approx(heading, abs=1e-4)


@pytest.mark.parametrize(
    ("speed", "heading"),
    [(0.5, math.pi / 2), (2.0, math.pi / 2), (1.0, 1.0), (-1.0, -math.pi / 2)],
)
def test_drive_into_wall(robot, step, init, simple_walls, speed, heading):
    """The simple maze's wall at y in [3, 4], x in [3, 10]: drive at it from (5, 1.5)."""
    model = robot.with_walls(simple_walls)
    c, h, a = simple_walls.center, simple_walls.half_size, simple_walls.active
    data = init(model, jnp.array([5.0, 1.5, heading]))
    ref = jnp.array([5.0, 1.5, heading])
    hits, ref_hits, pens = [], [], []
    for _ in range(30):
        data, pose, collided, pen = step(model, data, speed, 0.0)
        ref = g.unicycle_step(ref, speed, 0.0, DT)  # the free path, through the wall
        hits.append(bool(collided))
        ref_hits.append(bool(g.collides(ref[:2], RADIUS, c, h, a)))
        pens.append(float(pen))
        # the contacts left in data are the final pose's, and match the analytic depth
        analytic = float(g.circle_box_penetration(pose[:2], RADIUS, c, h, a))
        assert float(robot.contact_penetration(data)) == pytest.approx(
            analytic, abs=CONTACT_VS_ANALYTIC
        )
        assert float(pen) >= analytic - CONTACT_VS_ANALYTIC  # max over substeps
    assert any(hits)
    first, ref_first = hits.index(True), ref_hits.index(True)
    assert abs(first - ref_first) <= 1, (first, ref_first)  # no early or missed contact
    assert all(hits[first:])  # keeps pushing against the wall
    assert max(pens) < MAX_PENETRATION, max(pens)
    assert float(pose[1]) < 3.0 - RADIUS + MAX_PENETRATION  # stopped in front of it


# ------------------------------------------------------------------------- per-env walls
NUM_ENVS = 8


@pytest.fixture(scope="module")
def env_walls() -> mazes.Walls:
    ms = [mazes.builtin_maze("simple"), mazes.builtin_maze("complex")]
    ms += mazes.random_maze_bank(NUM_ENVS - 2, num_slots=SLOTS, seed=3)
    return mazes.stack_walls(ms, SLOTS)


@pytest.fixture(scope="module")
def batched(robot):
    """jit(vmap(init)), jit(vmap(step)) over per-env models, each allowed a single trace."""
    axes = robot.model_axes

    @jax.jit
    @chex.assert_max_traces(n=1)
    def vinit(models, poses):
        return jax.vmap(robot.init, in_axes=(axes, 0))(models, poses)

    @jax.jit
    @chex.assert_max_traces(n=1)
    def vstep(models, data, v, omega):
        return jax.vmap(robot.step, in_axes=(axes, 0, 0, 0))(models, data, v, omega)

    return vinit, vstep


def test_per_env_walls_vmapped(robot, batched, env_walls):
    vinit, vstep = batched
    rng = np.random.default_rng(1)
    # start every robot at a free cell centre of its own maze
    bank_free = [
        m.cell_centers(m.placement_cells())
        for m in [mazes.builtin_maze("simple"), mazes.builtin_maze("complex")]
        + mazes.random_maze_bank(NUM_ENVS - 2, num_slots=SLOTS, seed=3)
    ]
    any_hit = np.zeros(NUM_ENVS, bool)
    penetration = jax.vmap(g.circle_box_penetration, in_axes=(0, None, 0, 0, 0))
    for order in (np.arange(NUM_ENVS), np.roll(np.arange(NUM_ENVS), 3)):
        walls = jax.tree.map(lambda x, o=order: x[o], env_walls)  # new layouts, same trace
        xy = np.stack([bank_free[i][rng.integers(len(bank_free[i]))] for i in order])
        yaw = rng.uniform(-3, 3, (NUM_ENVS, 1))
        poses = jnp.asarray(np.concatenate([xy, yaw], -1), jnp.float32)
        models = robot.batch_with_walls(walls)
        data = vinit(models, poses)
        for k in range(12):
            v = jnp.full(NUM_ENVS, 1.5, jnp.float32)
            omega = jnp.asarray(rng.uniform(-1, 1, NUM_ENVS), jnp.float32) * (k % 2)
            data, pose, collided, pen = vstep(models, data, v, omega)
            assert np.isfinite(np.asarray(pose)).all() and np.isfinite(np.asarray(pen)).all()
            assert (np.asarray(pen) < MAX_PENETRATION).all()
            analytic = penetration(pose[:, :2], RADIUS, walls.center, walls.half_size, walls.active)
            contact = jax.vmap(robot.contact_penetration)(data)
            np.testing.assert_allclose(contact, analytic, atol=CONTACT_VS_ANALYTIC)
            any_hit |= np.asarray(collided)
    assert any_hit.sum() >= 2  # walls were met, each env in its own maze


def test_import_prints_nothing():
    """MJX's "Failed to import warp" line (an optional GPU backend) does not reach users."""
    import subprocess
    import sys

    code = "import jaxnav.envs.robot.mjx_backend"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout == ""
