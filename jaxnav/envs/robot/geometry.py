"""Planar geometry for a circular differential-drive robot among axis-aligned box walls.

Pure JAX, no Python loops over walls or rays: every function works on one robot and is meant
to be ``jit``-ed and ``vmap``-ed over environments by the caller. Frames and units: metres,
x right, y up, angles in radians counter-clockwise from +x. A pose is ``float32[3]``
``(x, y, theta)`` with ``theta`` in ``(-pi, pi]``.

Walls are plain arrays (the layout of ``jaxnav.envs.robot.mazes.Walls``): ``center:
float32[W, 2]``, ``half_size: float32[W, 2]`` (axis-aligned boxes), ``active: bool[W]``.
Inactive slots (padding to a fixed ``W``) are ignored wherever they lie. Ray casts take the
boxes as corners ``lo, hi`` (``box_bounds``), computed once per maze bank.

- ``laser_angles`` / ``lasers`` / ``ray_box_distances``: range sensors (the paper's 7 over the
  front half, or any count over any field of view up to 360 degrees), by the analytic slab
  method (exact, finite for axis-aligned rays).
- ``circle_box_penetration`` / ``collides``: how deep the robot's disc is inside the walls.
- ``unicycle_step``: exact integration of ``(v, omega)`` held constant over ``dt``.
- ``move_with_walls``: the kinematic backend's step, which stops at the last collision-free
  sub-step pose instead of entering a wall; ``min_substeps`` picks a sub-step count that
  cannot skip through the thinnest wall.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxnav import backend

# A ray direction component below this magnitude counts as this much (of its sign): keeps
# 1/d finite and moves a hit by at most ~1e-12 * range.
_PARALLEL_EPS = 1e-12
# "No hit" distance, and where inactive boxes are put; finite, so that no inf - inf can
# produce NaN. Larger than any ray length of interest (clipped to max_range anyway).
_FAR = 1e30


def laser_angles(num: int = 7, fov: float = math.pi) -> jax.Array:
    """Laser directions relative to the heading, ascending (from the robot's right).

    ``fov < 2 pi``: evenly from ``-fov / 2`` to ``+fov / 2``, both ends included. The default
    is the paper's 7 lasers over the front half: -90, -60, -30, 0, 30, 60 and 90 degrees
    (index 0 is the robot's right, index 3 straight ahead, index 6 its left). ``num=1`` gives
    the single forward ray.

    ``fov >= 2 pi`` (a full circle): ``num`` beams ``2 pi / num`` apart, one straight ahead,
    in ``(-pi, pi]``; no beam repeats another (as -180 and +180 degrees would).
    """
    if num < 1:
        raise ValueError(f"num={num!r}: must be at least 1")
    if not fov > 0:
        raise ValueError(f"fov={fov!r}: must be positive")
    if num == 1:
        return jnp.zeros((1,), jnp.float32)
    if fov >= 2 * math.pi:
        k = np.arange(num) - (num - 1) // 2  # index (num - 1) // 2 is the forward beam
        return jnp.asarray(k * (2 * math.pi / num), jnp.float32)
    return jnp.asarray(np.linspace(-fov / 2, fov / 2, num), jnp.float32)  # float64, then cast


def box_bounds(
    center: jax.Array, half_size: jax.Array, active: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The boxes' lower and upper corners ``(lo, hi)``, ``float32[..., W, 2]`` each, as
    ``ray_box_distances`` takes them. An inactive slot becomes the point ``(1e30, 1e30)``,
    beyond any range, so no ray hits it wherever the slot lies.

    Works on any leading axes: compute it once for a whole maze bank, then index by layout,
    so that a step does not redo it per ray and box.
    """
    c = jnp.asarray(center, jnp.float32)
    h = jnp.asarray(half_size, jnp.float32)
    keep = jnp.asarray(active, bool)[..., None]
    return jnp.where(keep, c - h, _FAR), jnp.where(keep, c + h, _FAR)


def ray_box_distances(
    origin: jax.Array,
    directions: jax.Array,
    lo: jax.Array,
    hi: jax.Array,
    max_range: float | jax.Array,
    unrolled: bool | None = None,
) -> jax.Array:
    """Distance along each ray to the nearest box, clipped to ``max_range``.

    ``origin: [2]``, ``directions: [R, 2]`` (unit vectors, so distances are in metres; for
    other lengths the result is the ray parameter ``t`` of ``origin + t * direction``),
    ``lo, hi: [W, 2]`` the boxes' corners (``box_bounds``) -> ``float32[R]``.

    Slab method: per axis the ray is inside the box's slab for ``t`` between ``(lo - o) / d``
    and ``(hi - o) / d``; the box is hit where the two intervals overlap at some ``t >= 0``,
    first at ``max(t_near, 0)``. A ray starting inside a box (boundary included) therefore
    measures 0. A direction component below 1e-12 in magnitude counts as 1e-12 of its sign:
    parallel to a slab, the ray stays inside it (origin within) or outside it for far longer
    than any range, with no per-box special case. The one case this decides is a ray running
    exactly along a face: it hits the box along the face it would enter by that tilt (the
    bottom face for a rightward ray) and misses it along the opposite one. Rays that hit
    nothing within ``max_range`` return exactly ``max_range``.

    ``unrolled`` picks how the nearest box is found, with the same result bit for bit (a
    minimum is exact in any order): a reduction over the boxes (``False``), or a chain of
    elementwise minimums box after box (``True``). ``None``: the backend's choice
    (``backend.ray_cast_unrolled``: the chain except on a CPU).
    """
    if unrolled is None:
        unrolled = backend.ray_cast_unrolled()
    origin = jnp.asarray(origin, jnp.float32)
    d = jnp.asarray(directions, jnp.float32)
    tilt = jnp.where(jnp.signbit(d), -_PARALLEL_EPS, _PARALLEL_EPS)
    inv = 1.0 / jnp.where(jnp.abs(d) < _PARALLEL_EPS, tilt, d)  # [R, 2]
    # boxes on the leading axis, rays minor: the nearest box is then a reduction over a major
    # axis, which XLA's CPU backend vectorizes over the rays (RobotNav-v0's 32 rays and 39
    # boxes step faster), or a chain over slices of whole rays
    t1 = (jnp.asarray(lo, jnp.float32)[:, None] - origin) * inv  # [W, R, 2]
    t2 = (jnp.asarray(hi, jnp.float32)[:, None] - origin) * inv
    t_near = jnp.minimum(t1, t2)
    t_far = jnp.maximum(t1, t2)
    # x and y by hand, not jnp.max(axis=-1): reductions over 2 made XLA cut the step into
    # kernels passing [R, W, 2] arrays through memory (with circle_box_penetration's same
    # change, faster on CPU and GPU: docs/results-history.md)
    enter = jnp.maximum(t_near[..., 0], t_near[..., 1])  # [W, R]
    leave = jnp.minimum(t_far[..., 0], t_far[..., 1])
    dist = jnp.where((enter <= leave) & (leave >= 0.0), jnp.maximum(enter, 0.0), _FAR)
    if unrolled:
        far = jnp.full(dist.shape[1:], _FAR, jnp.float32)
        nearest = functools.reduce(jnp.minimum, list(dist), far)
    else:
        nearest = jnp.min(dist, axis=0, initial=_FAR)
    return jnp.minimum(nearest, jnp.asarray(max_range, jnp.float32))


def lasers(
    pose: jax.Array,
    lo: jax.Array,
    hi: jax.Array,
    angles: jax.Array,
    max_range: float | jax.Array,
) -> jax.Array:
    """Laser ranges ``float32[R]`` from the robot's centre ``pose[:2]`` along ``pose[2] +
    angles`` (see ``laser_angles``), to the nearest wall (corners ``lo, hi`` from
    ``box_bounds``), clipped to ``max_range``.

    Measured from the centre, not the robot's rim: subtract the radius for a clearance.
    """
    pose = jnp.asarray(pose, jnp.float32)
    heading = pose[2] + jnp.asarray(angles, jnp.float32)
    directions = jnp.stack([jnp.cos(heading), jnp.sin(heading)], axis=-1)
    return ray_box_distances(pose[:2], directions, lo, hi, max_range)


def circle_box_penetration(
    position: jax.Array,
    radius: float | jax.Array,
    center: jax.Array,
    half_size: jax.Array,
    active: jax.Array,
) -> jax.Array:
    """Largest penetration depth ``float32[]`` of the disc (``position: [2]``, ``radius``)
    into any active box; 0 when it touches or clears all of them.

    Closest-point method: with ``q`` the point of the box closest to the centre, a centre
    outside the box penetrates by ``radius - |p - q|``. A centre inside the box (``q == p``)
    penetrates by ``radius`` plus its distance to the nearest face: the distance the disc
    must move to get out, continuous with the outside formula at the boundary.
    """
    p = jnp.asarray(position, jnp.float32)
    c = jnp.asarray(center, jnp.float32)
    h = jnp.asarray(half_size, jnp.float32)
    rel = p - c  # [W, 2]
    closest = jnp.clip(rel, -h, h)
    gap = rel - closest
    # x and y by hand, for the reason given in ray_box_distances
    d2 = gap[:, 0] * gap[:, 0] + gap[:, 1] * gap[:, 1]
    outside = d2 > 0.0
    dist = jnp.where(outside, jnp.sqrt(jnp.where(outside, d2, 1.0)), 0.0)  # NaN-free gradient
    inside = h - jnp.abs(rel)
    depth_inside = jnp.minimum(inside[:, 0], inside[:, 1])
    pen = jnp.asarray(radius, jnp.float32) + jnp.where(outside, -dist, depth_inside)
    pen = jnp.where(jnp.asarray(active, bool), pen, 0.0)
    return jnp.max(pen, initial=0.0)


def collides(
    position: jax.Array,
    radius: float | jax.Array,
    center: jax.Array,
    half_size: jax.Array,
    active: jax.Array,
) -> jax.Array:
    """Whether the disc overlaps an active box (penetration > 0; touching is no collision)."""
    return circle_box_penetration(position, radius, center, half_size, active) > 0.0


def wrap_angle(theta: jax.Array) -> jax.Array:
    """``theta`` wrapped to ``(-pi, pi]``."""
    theta = jnp.asarray(theta, jnp.float32)
    wrapped = jnp.pi - jnp.mod(jnp.pi - theta, 2 * jnp.pi)
    return jnp.where(wrapped <= -jnp.pi, wrapped + 2 * jnp.pi, wrapped)  # mod rounding to 2pi


def _sinc(a: jax.Array) -> jax.Array:
    """sin(a) / a, with its Taylor series near 0 (error < 1e-20 there; no 0/0)."""
    small = jnp.abs(a) < 1e-3
    safe = jnp.where(small, 1.0, a)
    a2 = a * a
    return jnp.where(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, jnp.sin(safe) / safe)


def unicycle_step(
    pose: jax.Array, v: float | jax.Array, omega: float | jax.Array, dt: float | jax.Array
) -> jax.Array:
    """Exact unicycle motion with forward speed ``v`` (m/s) and turn rate ``omega`` (rad/s)
    held for ``dt`` seconds; returns the new pose with theta wrapped to ``(-pi, pi]``.

    The robot follows an arc of radius ``v / omega`` (a straight line when ``omega == 0``).
    Written in chord form, which has no ``1 / omega``: the displacement is the chord of
    length ``v dt sinc(omega dt / 2)`` along the mean heading ``theta + omega dt / 2``, equal
    to ``(v / omega) (sin(theta') - sin(theta), cos(theta) - cos(theta'))`` for
    ``omega != 0`` and smooth through ``omega = 0``. Steps compose exactly: two steps of
    ``dt / 2`` equal one of ``dt``.
    """
    pose = jnp.asarray(pose, jnp.float32)
    v = jnp.asarray(v, jnp.float32)
    omega = jnp.asarray(omega, jnp.float32)
    dt = jnp.asarray(dt, jnp.float32)
    half_turn = 0.5 * omega * dt
    chord = v * dt * _sinc(half_turn)
    mid = pose[2] + half_turn
    x = pose[0] + chord * jnp.cos(mid)
    y = pose[1] + chord * jnp.sin(mid)
    return jnp.stack([x, y, wrap_angle(pose[2] + omega * dt)])


def min_substeps(max_speed: float, dt: float, min_half_size: float) -> int:
    """Smallest sub-step count for ``move_with_walls`` with which one sub-step moves strictly
    less than ``min_half_size`` (the thinnest wall's smaller half-size) at ``|v| <=
    max_speed``: ``floor(max_speed * dt / min_half_size) + 1``. A plain Python int (a static
    shape)."""
    if max_speed < 0 or dt < 0 or min_half_size <= 0:
        raise ValueError(
            f"max_speed={max_speed!r}, dt={dt!r}, min_half_size={min_half_size!r}: need "
            "max_speed >= 0, dt >= 0, min_half_size > 0"
        )
    return int(math.floor(max_speed * dt / min_half_size)) + 1


def move_with_walls(
    pose: jax.Array,
    v: float | jax.Array,
    omega: float | jax.Array,
    dt: float | jax.Array,
    radius: float | jax.Array,
    center: jax.Array,
    half_size: jax.Array,
    active: jax.Array,
    substeps: int = 8,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The kinematic backend's step: unicycle motion over ``dt`` that stops at walls.

    The motion is sampled at ``substeps`` sub-step poses ``unicycle_step(pose, v, omega, k dt
    / substeps)``, k = 1..substeps (the same poses as chaining sub-steps, since unicycle steps
    compose exactly, but computed in parallel and without accumulated rounding). The robot
    ends at the last pose before the first one whose disc penetrates an active wall, so it
    stops in front of the wall, up to one sub-step short of contact, with the heading it had
    there; without a collision the result equals ``unicycle_step(pose, v, omega, dt)``.

    Returns ``(new_pose, collided, penetration)``: ``collided`` is whether any sub-step pose
    (or the start) penetrates a wall; ``penetration`` is the depth at ``new_pose``, which is 0
    whenever the start pose is collision-free (a start inside a wall is an invalid state: the
    robot then stays put and its depth is reported).

    Thin walls: a swept disc can skip a wall only if one sub-step travels across it, and the
    wall inflated by the robot radius is at least ``2 (half_size_min + radius)`` thick. With
    ``substeps >= min_substeps(max |v|, dt, thinnest half-size)`` one sub-step travels (arc
    length) less than the thinnest half-size, so no crossing is missed; between two free
    samples the path can graze a corner by less than half a sub-step. ``substeps`` is a
    static Python int (``static_argnames="substeps"`` when jitting this function directly).
    """
    pose = jnp.asarray(pose, jnp.float32)
    start = pose.at[2].set(wrap_angle(pose[2]))
    fractions = jnp.arange(1, substeps + 1, dtype=jnp.float32) / substeps  # last is exactly 1
    dt = jnp.asarray(dt, jnp.float32)
    samples = jax.vmap(lambda f: unicycle_step(pose, v, omega, dt * f))(fractions)
    poses = jnp.concatenate([start[None], samples], axis=0)  # [S + 1, 3]
    pen = jax.vmap(lambda p: circle_box_penetration(p[:2], radius, center, half_size, active))(
        poses[:, :2]
    )
    hits = pen > 0.0
    collided = jnp.any(hits)
    first_hit = jnp.argmax(hits)  # first True; 0 when the start itself collides
    index = jnp.where(collided, jnp.maximum(first_hit - 1, 0), substeps)
    return poses[index], collided, pen[index]
