"""jaxnav.envs.robot.geometry against plain-numpy float64 references written here.

The references use different methods from the JAX code (rays: intersection with each of a
box's four faces instead of the slab method; discs: the box's signed distance function
instead of the closest point), and never call it. Inputs are rounded to float32 first, so
both sides see the same numbers. A ray that grazes a box corner or face is ill-conditioned:
a 1e-5 change of its origin or angle moves its reading far more than float32 rounding of the
JAX side can be held to; such rays (a fraction of a percent of random ones) are left out of
the random comparisons, and grazing and axis-aligned cases are checked exactly instead.
"""

from __future__ import annotations

import math
from functools import partial

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxnav.envs.robot import geometry as g

MAX_RANGE = 10.0
W = 8  # wall slots per scene (some inactive)
SETTINGS = settings(max_examples=40, deadline=None)
PAPER_DEG = np.array([-90.0, -60.0, -30.0, 0.0, 30.0, 60.0, 90.0])
AXES = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]], np.float32)


# ------------------------------------------------------------------ numpy references
def ref_ray(o, d, centers, halves, active, max_range=MAX_RANGE) -> float:
    """Nearest hit of ray o + t d (t >= 0) over active boxes, by the four faces of each box."""
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    best = float(max_range)
    for c, h, a in zip(centers, halves, active, strict=True):
        if not a:
            continue
        lo, hi = np.asarray(c, np.float64) - h, np.asarray(c, np.float64) + h
        if np.all(lo <= o) and np.all(o <= hi):
            return 0.0
        for axis in (0, 1):
            if d[axis] == 0.0:
                continue  # parallel to these faces (grazing along one is hit by the other pair)
            other = 1 - axis
            for face in (lo[axis], hi[axis]):
                t = (face - o[axis]) / d[axis]
                if t >= 0.0 and lo[other] <= o[other] + t * d[other] <= hi[other]:
                    best = min(best, t)
    return best


def ref_rays(o, dirs, centers, halves, active) -> np.ndarray:
    return np.array([ref_ray(o, d, centers, halves, active) for d in dirs])


def well_conditioned(o, dirs, centers, halves, active, eps=1e-5, tol=1e-3) -> np.ndarray:
    """Rays whose reference reading moves by < tol when origin or angle move by eps."""
    o = np.asarray(o, np.float64)
    dirs = np.asarray(dirs, np.float64)
    nominal = ref_rays(o, dirs, centers, halves, active)
    ok = np.ones(len(dirs), bool)
    rot = [np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]) for a in (eps, -eps)]
    for shift in ([eps, 0], [-eps, 0], [0, eps], [0, -eps]):
        ok &= np.abs(ref_rays(o + shift, dirs, centers, halves, active) - nominal) < tol
    for r in rot:
        ok &= np.abs(ref_rays(o, dirs @ r.T, centers, halves, active) - nominal) < tol
    return ok


def ref_penetration(p, radius, centers, halves, active) -> float:
    """max(0, radius - signed distance to each active box), by the box SDF."""
    best = 0.0
    for c, h, a in zip(centers, halves, active, strict=True):
        if not a:
            continue
        q = np.abs(np.asarray(p, np.float64) - c) - h
        sdf = np.linalg.norm(np.maximum(q, 0.0)) + min(max(q[0], q[1]), 0.0)
        best = max(best, radius - sdf)
    return best


def ref_arc(pose, v, omega, dt) -> np.ndarray:
    """Unicycle in float64 by the textbook formulas: the 1/omega arc, or a straight line for
    |omega| < 1e-9 (where the arc's cancellation error would exceed the line's ~v dt^2 omega)."""
    x, y, th = (float(c) for c in pose)
    th2 = th + omega * dt
    if abs(omega) < 1e-9:
        return np.array([x + v * dt * math.cos(th), y + v * dt * math.sin(th), th2])
    return np.array(
        [
            x + v / omega * (math.sin(th2) - math.sin(th)),
            y - v / omega * (math.cos(th2) - math.cos(th)),
            th2,
        ]
    )


def angle_diff(a, b):
    return np.abs((np.asarray(a, np.float64) - b + np.pi) % (2 * np.pi) - np.pi)


# ------------------------------------------------------------------ strategies
def f32(lo: float, hi: float) -> st.SearchStrategy[float]:
    """float32 values in [lo, hi] (bounds rounded inwards to float32)."""
    lo32, hi32 = np.float32(lo), np.float32(hi)
    lo32 = lo32 if lo32 >= lo else np.nextafter(lo32, np.float32(np.inf))
    hi32 = hi32 if hi32 <= hi else np.nextafter(hi32, np.float32(-np.inf))
    return st.floats(float(lo32), float(hi32), width=32, allow_subnormal=False)


coord = f32(-4.0, 4.0)
half = f32(0.02, 1.0)
box = st.tuples(coord, coord, half, half, st.booleans())


@st.composite
def scenes(draw):
    """(origin, centers, halves, active): W boxes, the origin outside every active one (boxes
    that contain it, with a 1e-3 margin, are made inactive but stay, to be ignored)."""
    boxes = draw(st.lists(box, min_size=W, max_size=W))
    o = np.array([draw(coord), draw(coord)], np.float32)
    centers = np.array([b[:2] for b in boxes], np.float32)
    halves = np.array([b[2:4] for b in boxes], np.float32)
    active = np.array([b[4] for b in boxes], bool)
    around = np.all(np.abs(o - centers) <= halves + 1e-3, axis=1)
    return o, centers, halves, active & ~around


unit_angle = st.floats(-math.pi, math.pi, allow_subnormal=False)


# ------------------------------------------------------------------ jitted functions
def boxes_rays(o, dirs, centers, halves, active, max_range):
    return g.ray_box_distances(o, dirs, *g.box_bounds(centers, halves, active), max_range)


def boxes_lasers(pose, centers, halves, active, angles, max_range):
    return g.lasers(pose, *g.box_bounds(centers, halves, active), angles, max_range)


_rays = jax.jit(boxes_rays)
_lasers = jax.jit(boxes_lasers)
_pen = jax.jit(g.circle_box_penetration)
_step = jax.jit(g.unicycle_step)
_move = jax.jit(g.move_with_walls, static_argnames="substeps")


def test_laser_angles_are_the_papers():
    np.testing.assert_allclose(np.rad2deg(np.asarray(g.laser_angles())), PAPER_DEG, atol=1e-5)
    assert g.laser_angles().dtype == jnp.float32
    np.testing.assert_allclose(
        np.asarray(g.laser_angles(3, math.pi / 2)), [-np.pi / 4, 0, np.pi / 4]
    )
    assert g.laser_angles(1).tolist() == [0.0]
    with pytest.raises(ValueError, match="num"):
        g.laser_angles(0)


# ------------------------------------------------------------------ rays
@SETTINGS
@given(scene=scenes(), angles=st.lists(unit_angle, min_size=7, max_size=7))
def test_ray_box_distances_match_reference(scene, angles):
    o, centers, halves, active = scene
    dirs = np.concatenate(
        [AXES, np.stack([np.cos(angles), np.sin(angles)], axis=1).astype(np.float32)]
    )  # 4 exactly axis-aligned rays (components exactly 0) + 7 random ones
    got = np.asarray(_rays(o, dirs, centers, halves, active, MAX_RANGE))
    assert np.all(np.isfinite(got))
    want = ref_rays(o, dirs, centers, halves, active)
    ok = well_conditioned(o, dirs, centers, halves, active)
    np.testing.assert_allclose(got[ok], want[ok], atol=1e-4, rtol=0)
    assert np.all(got[want == MAX_RANGE] == MAX_RANGE)  # no hit: exactly max_range


@SETTINGS
@given(
    scene=scenes(),
    theta=st.one_of(unit_angle, st.sampled_from([k * math.pi / 6 for k in range(-6, 7)])),
)
def test_lasers_match_reference(scene, theta):
    o, centers, halves, active = scene
    pose = np.array([o[0], o[1], theta], np.float32)
    got = np.asarray(_lasers(pose, centers, halves, active, g.laser_angles(), MAX_RANGE))
    heading = float(pose[2]) + np.deg2rad(PAPER_DEG)
    dirs = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    want = ref_rays(o, dirs, centers, halves, active)
    ok = well_conditioned(o, dirs, centers, halves, active)
    np.testing.assert_allclose(got[ok], want[ok], atol=1e-4, rtol=0)
    assert np.all(got[want == MAX_RANGE] == MAX_RANGE)


def test_rays_bulk_random_scenes_vmapped():
    """300 seeded scenes in one vmapped call; under 1% of rays are ill-conditioned."""
    rng = np.random.default_rng(0)
    n = 300
    origins = rng.uniform(-4, 4, (n, 2)).astype(np.float32)
    centers = rng.uniform(-4, 4, (n, W, 2)).astype(np.float32)
    halves = rng.uniform(0.02, 1.0, (n, W, 2)).astype(np.float32)
    around = np.all(np.abs(origins[:, None] - centers) <= halves + 1e-3, axis=2)
    active = (rng.random((n, W)) < 0.8) & ~around
    theta = rng.uniform(-np.pi, np.pi, n).astype(np.float32)
    poses = np.concatenate([origins, theta[:, None]], axis=1)
    vl = jax.jit(jax.vmap(boxes_lasers, in_axes=(0, 0, 0, 0, None, None)))
    got = np.asarray(vl(poses, centers, halves, active, g.laser_angles(), MAX_RANGE))
    compared = 0
    for i in range(n):
        heading = float(poses[i, 2]) + np.deg2rad(PAPER_DEG)
        dirs = np.stack([np.cos(heading), np.sin(heading)], axis=1)
        want = ref_rays(origins[i], dirs, centers[i], halves[i], active[i])
        ok = well_conditioned(origins[i], dirs, centers[i], halves[i], active[i])
        np.testing.assert_allclose(got[i][ok], want[ok], atol=1e-4, rtol=0)
        compared += ok.sum()
    assert compared >= 0.99 * n * 7
    assert 0 < (got == MAX_RANGE).mean() < 1  # both hits and misses occurred


def test_nearest_box_chain_and_reduction_agree_bit_for_bit():
    """The chain of minimums a GPU runs and the reduction a CPU runs give the same ranges, on
    random scenes with rays starting inside boxes, and with no wall slots at all."""
    rng = np.random.default_rng(1)
    n, rays = 200, 32
    origins = rng.uniform(-4, 4, (n, 2)).astype(np.float32)
    centers = rng.uniform(-4, 4, (n, 39, 2)).astype(np.float32)
    halves = rng.uniform(0.02, 1.0, (n, 39, 2)).astype(np.float32)
    active = rng.random((n, 39)) < 0.8
    heading = rng.uniform(-np.pi, np.pi, (n, rays))
    dirs = np.stack([np.cos(heading), np.sin(heading)], -1).astype(np.float32)
    lo, hi = g.box_bounds(centers, halves, active)
    for walls in (39, 0):
        forms = [
            jax.jit(jax.vmap(partial(g.ray_box_distances, max_range=5.0, unrolled=unrolled)))(
                origins, dirs, lo[:, :walls], hi[:, :walls]
            )
            for unrolled in (True, False)
        ]
        chex.assert_shape(forms, (n, rays))
        np.testing.assert_array_equal(*forms)
    # the scenes hold every case: rays from inside a box, misses, hits in between
    hits = np.asarray(jax.vmap(partial(g.ray_box_distances, max_range=5.0))(origins, dirs, lo, hi))
    assert (hits == 0.0).any() and (hits == 5.0).any() and ((hits > 0) & (hits < 5)).any()


def test_rays_axis_aligned_grazing_inside_and_inactive():
    c = np.array([[2.0, 0.0], [0.0, -3.0], [0.0, 0.0]], np.float32)
    h = np.array([[0.5, 0.5], [1.0, 0.25], [0.1, 0.1]], np.float32)
    active = np.array([True, True, False])  # the third box holds the origin but is inactive
    dirs = np.concatenate([AXES, [[0.6, 0.8]]]).astype(np.float32)
    got = np.asarray(_rays(np.zeros(2, np.float32), dirs, c, h, active, MAX_RANGE))
    np.testing.assert_array_equal(got, [1.5, MAX_RANGE, MAX_RANGE, 2.75, MAX_RANGE])
    # exactly along a face, direction (1, 0) counts as tilted up by 1e-12: it enters the
    # box along its bottom face (y = -0.5), at the corner, and leaves it along its top face
    got = _rays(np.array([0.0, -0.5], np.float32), AXES[:1], c, h, active, MAX_RANGE)
    assert float(got[0]) == 1.5
    got = _rays(np.array([0.0, 0.5], np.float32), AXES[:1], c, h, active, MAX_RANGE)
    assert float(got[0]) == MAX_RANGE
    # the same for -0.0 components: (-1, -0.0) counts as tilted down, along the top face
    left = np.array([[-1.0, -0.0]], np.float32)
    got = _rays(np.array([4.0, 0.5], np.float32), left, c, h, active, MAX_RANGE)
    assert float(got[0]) == 1.5
    # just above the face: a miss, exactly max_range
    got = _rays(np.array([0.0, 0.5001], np.float32), AXES[:1], c, h, active, MAX_RANGE)
    assert float(got[0]) == MAX_RANGE
    # origin inside an active box: 0 in every direction
    got = _rays(np.array([2.1, 0.2], np.float32), dirs, c, h, active, MAX_RANGE)
    np.testing.assert_array_equal(got, np.zeros(5))
    # a hit beyond max_range is clipped; no active wall at all is max_range
    assert float(_rays(np.zeros(2, np.float32), AXES[:1], c, h, active, 1.0)[0]) == 1.0
    none = np.zeros(3, bool)
    assert np.all(np.asarray(_rays(np.zeros(2, np.float32), dirs, c, h, none, 3.0)) == 3.0)


def test_rays_zero_wall_slots_and_gradient_finite():
    got = boxes_rays(
        jnp.zeros(2),
        jnp.asarray(AXES),
        jnp.zeros((0, 2)),
        jnp.zeros((0, 2)),
        jnp.zeros((0,), bool),
        5.0,
    )
    np.testing.assert_array_equal(got, np.full(4, 5.0))
    c, h, a = jnp.array([[2.0, 0.0]]), jnp.array([[0.5, 0.5]]), jnp.array([True])
    grad = jax.grad(lambda o: boxes_rays(o, jnp.asarray(AXES), c, h, a, 10.0).sum())
    assert np.all(np.isfinite(np.asarray(grad(jnp.zeros(2)))))


# ------------------------------------------------------------------ discs
@SETTINGS
@given(scene=scenes(), p=st.tuples(coord, coord), radius=f32(0.05, 1.0))
def test_circle_box_penetration_matches_reference(scene, p, radius):
    _, centers, halves, active = scene  # p may lie inside boxes here
    p = np.array(p, np.float32)
    got = float(_pen(p, radius, centers, halves, active))
    want = ref_penetration(p, float(np.float32(radius)), centers, halves, active)
    assert got >= 0.0
    assert abs(got - max(want, 0.0)) < 1e-5
    assert bool(g.collides(p, radius, centers, halves, active)) == (got > 0)


def test_collides_far_touching_and_overlapping():
    c = np.array([[0.0, 0.0], [50.0, 50.0]], np.float32)
    h = np.array([[1.0, 0.5], [100.0, 100.0]], np.float32)  # the huge one is inactive
    a = np.array([True, False])
    r = 0.25
    assert not g.collides(np.array([3.0, 3.0]), r, c, h, a)
    assert float(g.circle_box_penetration(np.array([3.0, 3.0]), r, c, h, a)) == 0.0
    assert not g.collides(np.array([1.25, 0.0]), r, c, h, a)  # touching the right face
    assert g.collides(np.array([1.2, 0.0]), r, c, h, a)
    np.testing.assert_allclose(
        g.circle_box_penetration(np.array([1.2, 0.0]), r, c, h, a), 0.05, atol=1e-6
    )
    # corner: distance to (1, 0.5) is 0.2 -> depth 0.05
    p = np.array([1.0 + 0.12, 0.5 + 0.16], np.float32)
    np.testing.assert_allclose(g.circle_box_penetration(p, r, c, h, a), 0.05, atol=1e-6)
    # centre inside: radius + distance to the nearest face (0.1 to the top)
    np.testing.assert_allclose(
        g.circle_box_penetration(np.array([0.0, 0.4]), r, c, h, a), 0.35, atol=1e-6
    )
    assert g.collides(np.array([0.0, 0.0]), r, c, h, a)


# ------------------------------------------------------------------ unicycle
poses = st.tuples(f32(-5, 5), f32(-5, 5), f32(-math.pi, math.pi))
speed = f32(-2.0, 2.0)
turn = f32(-4.0, 4.0)
dts = f32(0.01, 1.0)


@SETTINGS
@given(pose=poses, v=speed, dt=dts)
def test_unicycle_forward_moves_along_heading(pose, v, dt):
    pose = np.array(pose, np.float32)
    got = np.asarray(_step(pose, v, 0.0, dt))
    th = float(pose[2])
    np.testing.assert_allclose(
        got[:2], pose[:2] + v * dt * np.array([np.cos(th), np.sin(th)]), atol=2e-6
    )
    assert angle_diff(got[2], th) < 1e-6


@SETTINGS
@given(pose=poses, omega=turn, dt=dts)
def test_unicycle_pure_rotation(pose, omega, dt):
    pose = np.array(pose, np.float32)
    got = np.asarray(_step(pose, 0.0, omega, dt))
    np.testing.assert_array_equal(got[:2], pose[:2])
    assert angle_diff(got[2], float(pose[2]) + omega * dt) < 2e-6
    assert -np.pi < got[2] <= np.pi


@SETTINGS
@given(pose=poses, v=speed, omega=turn, dt=dts)
def test_unicycle_matches_arc_formula_and_composes(pose, v, omega, dt):
    pose = np.array(pose, np.float32)
    got = np.asarray(_step(pose, v, omega, dt))
    if abs(omega) > 0.05:  # the 1/omega textbook form is itself inaccurate near 0
        want = ref_arc(pose, float(np.float32(v)), float(np.float32(omega)), float(np.float32(dt)))
        np.testing.assert_allclose(got[:2], want[:2], atol=1e-5)
        assert angle_diff(got[2], want[2]) < 2e-6
    half = np.asarray(_step(_step(pose, v, omega, dt / 2), v, omega, dt / 2))
    np.testing.assert_allclose(half[:2], got[:2], atol=1e-5)
    assert angle_diff(half[2], got[2]) < 2e-6
    assert -np.pi < got[2] <= np.pi


def test_unicycle_omega_to_zero_is_continuous():
    pose = np.array([0.3, -1.2, 0.7], np.float32)
    straight = np.asarray(_step(pose, 1.5, 0.0, 1.0))
    for omega in (1e-8, -1e-8, 1e-6, 1e-4):
        np.testing.assert_allclose(
            _step(pose, 1.5, omega, 1.0), straight, atol=2 * abs(omega) + 1e-6
        )
    # across the Taylor/sin switch (|omega dt / 2| = 1e-3), against float64 arcs
    for omega in (1.999e-3, 2.0e-3, 2.001e-3, 1e-2):
        want = ref_arc(pose, 1.5, float(np.float32(omega)), 1.0)
        np.testing.assert_allclose(_step(pose, 1.5, omega, 1.0), want, atol=1e-6)
    # gradients through omega = 0 are finite
    grad = jax.grad(lambda w: g.unicycle_step(jnp.asarray(pose), 1.5, w, 1.0).sum())(0.0)
    assert np.isfinite(grad)


def test_wrap_angle():
    x = np.array([0.0, np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 7.0, -7.0, 1e-9, -1e-9], np.float32)
    got = np.asarray(g.wrap_angle(x))
    assert np.all((got > -np.pi) & (got <= np.pi))
    assert np.all(angle_diff(got, x.astype(np.float64)) < 1e-6)
    assert got[2] == np.float32(np.pi)  # -pi maps to +pi
    # dense: float32 neighbours of multiples of pi, where rounding could leave the range
    rng = np.random.default_rng(3)
    near = np.arange(-20, 21)[:, None] * np.pi + rng.normal(0, 1e-6, (41, 2000))
    x = np.concatenate([near.ravel(), rng.uniform(-50, 50, 20000)]).astype(np.float32)
    got = np.asarray(jax.jit(g.wrap_angle)(x))
    assert np.all((got > -np.pi) & (got <= np.pi))
    assert np.all(angle_diff(got, x.astype(np.float64)) < 1e-5)


# ------------------------------------------------------------------ kinematic backend
RADIUS = 0.2
V_MAX, DT = 2.0, 0.5
# four thin walls around (0, 0), the thinnest half-size 0.05
WALLS_C = np.array([[1.0, 0.0], [-1.0, 0.3], [0.2, 1.0], [0.0, -1.2], [9, 9]], np.float32)
WALLS_H = np.array([[0.05, 1.0], [0.05, 0.8], [0.6, 0.05], [1.5, 0.1], [1e-3, 1e-3]], np.float32)
WALLS_A = np.array([True, True, True, True, False])
SUBSTEPS = g.min_substeps(V_MAX, DT, 0.05)


def test_min_substeps():
    assert SUBSTEPS == 21  # 2 m/s * 0.5 s / 0.05 m = 20 -> strictly less needs 21
    assert g.min_substeps(1.0, 0.1, 0.3) == 1
    with pytest.raises(ValueError):
        g.min_substeps(1.0, 0.1, 0.0)


@SETTINGS
@given(
    xy=st.tuples(f32(-1.6, 1.6), f32(-1.6, 1.6)),
    theta=f32(-math.pi, math.pi),
    v=f32(-V_MAX, V_MAX),
    omega=turn,
)
def test_move_with_walls_never_ends_inside_a_wall(xy, theta, v, omega):
    pose = np.array([xy[0], xy[1], theta], np.float32)
    new, collided, pen = _move(
        pose, v, omega, DT, RADIUS, WALLS_C, WALLS_H, WALLS_A, substeps=SUBSTEPS
    )
    new = np.asarray(new)
    assert np.all(np.isfinite(new)) and -np.pi < new[2] <= np.pi
    if float(_pen(pose[:2], RADIUS, WALLS_C, WALLS_H, WALLS_A)) > 0:  # invalid start
        assert bool(collided) and float(pen) > 0
        np.testing.assert_array_equal(new[:2], pose[:2])  # stays put
        return
    assert float(pen) == 0.0
    assert ref_penetration(new[:2], RADIUS, WALLS_C, WALLS_H, WALLS_A) < 1e-5
    free = np.asarray(_step(pose, v, omega, DT))
    if not bool(collided):
        np.testing.assert_array_equal(new, free)
    # the end pose lies on the commanded path, at a sub-step sample
    samples = [pose] + [
        ref_arc(pose, float(np.float32(v)), float(np.float32(omega)), DT * k / SUBSTEPS)
        for k in range(1, SUBSTEPS + 1)
    ]
    assert min(np.abs(s[:2] - new[:2]).max() for s in samples) < 1e-4


def test_move_with_walls_stops_in_front_of_a_thin_wall():
    # heading +x at 2 m/s for 0.5 s would end at x = 1.0, in the wall at x = 1 +- 0.05, and at
    # 3 m/s beyond it: the robot must stop in front, within one sub-step of contact
    contact = 1.0 - 0.05 - RADIUS
    pose = np.array([0.0, 0.0, 0.0], np.float32)
    for v, substeps in ((2.0, SUBSTEPS), (3.0, g.min_substeps(3.0, DT, 0.05))):
        new, collided, pen = _move(
            pose, v, 0.0, DT, RADIUS, WALLS_C, WALLS_H, WALLS_A, substeps=substeps
        )
        new = np.asarray(new)
        sub = v * DT / substeps
        assert bool(collided) and float(pen) == 0.0
        assert contact - sub - 1e-6 <= new[0] <= contact + 1e-6
        assert new[1] == 0.0 and new[2] == 0.0
    # a single sub-step would jump over the wall (why min_substeps matters)
    new, collided, _ = _move(pose, 3.0, 0.0, DT, RADIUS, WALLS_C, WALLS_H, WALLS_A, substeps=1)
    assert not bool(collided) and float(new[0]) == 1.5
    # backing away from the wall is free
    start = np.array([contact - 0.01, 0.0, 0.0], np.float32)
    new, collided, _ = _move(start, -1.0, 0.0, DT, RADIUS, WALLS_C, WALLS_H, WALLS_A, substeps=8)
    assert not bool(collided)
    np.testing.assert_allclose(new, [contact - 0.51, 0.0, 0.0], atol=1e-6)


def test_move_with_walls_never_crosses_a_thin_wall():
    """2000 straight shots at the wall x = 1 +- 0.05 (|y| <= 1) from its left, fast enough to
    reach it: with min_substeps none crosses; with 1 sub-step some would."""
    rng = np.random.default_rng(4)
    n = 2000
    y = rng.uniform(-0.5, 0.5, n)
    pose = np.stack([rng.uniform(-0.7, 0.7, n), y, rng.uniform(-0.35, 0.35, n)], 1)
    v = rng.uniform(1.0, V_MAX, n)
    move = jax.jit(
        jax.vmap(g.move_with_walls, in_axes=(0, 0, None, None, None, None, None, None, None)),
        static_argnums=8,
    )
    args = (pose.astype(np.float32), v.astype(np.float32), 0.0, DT, RADIUS)
    walls = (WALLS_C, WALLS_H, WALLS_A)
    new, _, pen = move(*args, *walls, SUBSTEPS)
    assert np.all(np.asarray(new)[:, 0] <= 1.0 - 0.05 - RADIUS + 1e-6)
    assert np.all(np.asarray(pen) == 0.0)
    one, _, _ = move(*args, *walls, 1)
    assert np.mean(np.asarray(one)[:, 0] > 1.0) > 0.05  # about 13% jump over it


def test_move_with_walls_equals_unicycle_in_free_space():
    rng = np.random.default_rng(1)
    far_c, far_h = WALLS_C + 100.0, WALLS_H
    for _ in range(20):
        pose = rng.uniform([-3, -3, -np.pi], [3, 3, np.pi]).astype(np.float32)
        v, omega = float(rng.uniform(-2, 2)), float(rng.uniform(-4, 4))
        free = np.asarray(_step(pose, v, omega, DT))
        for c, a in ((far_c, WALLS_A), (WALLS_C, np.zeros(5, bool))):
            new, collided, pen = _move(pose, v, omega, DT, RADIUS, c, far_h, a, substeps=8)
            np.testing.assert_array_equal(np.asarray(new), free)
            assert not bool(collided) and float(pen) == 0.0


# ------------------------------------------------------------------ batching
def test_jit_vmap_4096_traces_once_and_finite():
    n = 4096
    rng = np.random.default_rng(2)

    @jax.jit
    @chex.assert_max_traces(n=1)
    def batch(pose, v, omega, centers, halves, active):
        def one(p, v, w, c, h, a):
            ranges = boxes_lasers(p, c, h, a, g.laser_angles(), MAX_RANGE)
            moved = g.move_with_walls(p, v, w, DT, RADIUS, c, h, a, substeps=SUBSTEPS)
            return ranges, g.circle_box_penetration(p[:2], RADIUS, c, h, a), moved

        return jax.vmap(one)(pose, v, omega, centers, halves, active)

    for _ in range(2):
        pose = rng.uniform([-3, -3, -np.pi], [3, 3, np.pi], (n, 3)).astype(np.float32)
        pose[:64, 2] = np.float32(np.pi / 2) * rng.integers(-2, 3, 64)  # near axis-aligned rays
        v = rng.uniform(-V_MAX, V_MAX, n).astype(np.float32)
        omega = rng.uniform(-4, 4, n).astype(np.float32)
        omega[::3] = 0.0
        omega[1::3] = 1e-9
        centers = rng.uniform(-3, 3, (n, 24, 2)).astype(np.float32)
        halves = rng.uniform(0.05, 0.5, (n, 24, 2)).astype(np.float32)
        active = rng.random((n, 24)) < 0.7
        ranges, pen, (new, collided, pen_after) = batch(pose, v, omega, centers, halves, active)
        assert ranges.shape == (n, 7) and new.shape == (n, 3) and collided.shape == (n,)
        for x in (ranges, pen, new, pen_after):
            assert np.all(np.isfinite(np.asarray(x)))
        assert np.all(np.asarray(ranges) >= 0) and np.all(np.asarray(ranges) <= MAX_RANGE)
        start_free = np.asarray(pen) == 0
        assert np.all(np.asarray(pen_after)[start_free] == 0)
        assert 0 < np.asarray(collided).mean() < 1


# ------------------------------------------------------------------ benchmark smoke
def test_benchmark_smoke(tmp_path):
    import json
    import sys
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[1])  # `benchmarks` is not installed
    if root not in sys.path:
        sys.path.insert(0, root)
    from benchmarks import robot_geometry

    out = tmp_path / "rg.json"
    argv = ["--num-envs", "8", "--walls", "6", "--steps", "3", "--rounds", "2", "--out", str(out)]
    result = robot_geometry.main(argv)
    data = json.loads(out.read_text())
    assert data == json.loads(json.dumps(result))
    assert [r["kind"] for r in data["results"]] == list(robot_geometry.KINDS)
    for r in data["results"]:
        assert r["walls"] == 6 and r["rays"] == 7 and len(r["run_s"]) == 2
        assert r["compile_s"] > 0 and r["env_steps_per_s"] > 0
    assert out.with_suffix(".md").read_text().startswith("| kind |")
