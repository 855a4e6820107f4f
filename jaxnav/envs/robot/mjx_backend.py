"""The circular robot stepped by MuJoCo MJX (the physics backend; ``geometry.py`` is the
kinematic one).

The robot is a body on slide-x, slide-y and hinge-z joints with a *sphere* collision geom (MJX
has no cylinder-box collider: ``NotImplementedError`` at ``put_model``), driven by velocity
actuators on the three joints. Every substep the actuator targets are rewritten from the
current heading, ``(v cos th, v sin th, omega)``, so the free body moves like a differential
drive robot (no wheels: a wheeled model hops and drifts unless the timestep is 0.005 s, and is
~50x slower). Walls are ``num_wall_slots`` static boxes on the world body; ``MjxRobot.with_walls``
writes one env's ``mazes.Walls`` into the model's ``geom_pos``, ``geom_size`` and
``geom_rbound`` (vmappable, so every env may have its own layout in one compiled step).

Settings (see ``build_model``; each chosen by measuring this robot's model in MJX 3.17):

- ``timestep`` x ``substeps`` = one 0.1 s control step: 0.02 s x 5 by default here; the env
  uses 0.05 s x 2 (``RobotConfig.mjx_substeps``), about 2x the throughput of 5 substeps with the
  same terminations on random play, at the cost of up to one substep of travel into a wall.
- Frictionless contacts (``condim=1``): the robot slides along walls; friction needs 3-6x
  larger constraint rows and buys nothing for a robot that only has to stop.
- Newton solver with ``iterations=1``, ``ls_iterations=4``: a handful of contact rows at most,
  one Newton step converges them well enough; the default (100 / 50) is ~8x slower.
- Custom numeric ``max_geom_pairs`` = 8. How MJX 3.17 reads it
  (``mujoco/mjx/_src/collision_driver.py``): ``_numeric(m, name)`` looks the name up among the
  model's ``<numeric>`` elements (-1 when absent). In ``collision`` every group of geom pairs
  (here one group: sphere vs box, condim 1) larger than ``max_geom_pairs`` is culled first by
  a bounding-sphere broad phase, ``|geom_xpos2 - geom_xpos1| - (rbound1 + rbound2)``, keeping
  the ``max_geom_pairs`` closest with ``lax.top_k``; ``make_condim`` caps the static contact
  count the same way, so the robot has exactly ``min(W, 8)`` contact slots (sphere-box emits
  one contact each) and the constraint arrays are that size. Hence ``geom_rbound`` must follow
  the per-env wall sizes, or the broad phase would rank walls by the compiled-in sizes.
  ``max_contact_points`` (a second cap, applied after narrow phase by most-penetrating
  contacts) is not set: it would only cut the same 8 again. Fewer than 8 pairs misses real
  contacts in a 34-wall maze (a long wall's bounding sphere is large and far-centred).
- A ``<material>`` is declared: ``mjx.ray`` crashes on a model without any.
- Zero gravity: nothing moves along z, and no floor is needed (no floor contacts to pay for).
- Velocity gains are *deadbeat*: ``kv = mass / timestep`` (and ``inertia / timestep`` for the
  hinge), so MuJoCo's semi-implicit Euler (``qvel += dt * kv / m * (u - qvel)``) reaches the
  commanded velocity in exactly one substep when unobstructed; larger gains overshoot and
  oscillate (``kv dt / m > 2`` diverges), smaller ones lag the command.
"""

from __future__ import annotations

import contextlib
import io
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxnav.envs.robot.geometry import wrap_angle
from jaxnav.envs.robot.mazes import PARKED_CENTER, PARKED_HALF_SIZE, Walls

# MJX prints "Failed to import warp" (its optional GPU backend, not used here) on import; keep
# every other line it prints
with contextlib.redirect_stdout(io.StringIO()) as _printed:
    from mujoco import mjx
sys.stdout.write("".join(x for x in _printed.getvalue().splitlines(True) if "warp" not in x))


MASS = 1.0  # kg; only the ratio to the gains matters for the kinematic behaviour
INERTIA_Z = 0.01  # kg m^2 about the hinge
WALL_HALF_HEIGHT = 0.5  # m; the sphere stays at z = 0, inside every wall's height
MAX_GEOM_PAIRS = 8
ROBOT_GEOM = "robot"


def _xml(num_wall_slots: int, radius: float, timestep: float) -> str:
    kv_lin = MASS / timestep  # deadbeat velocity tracking, see the module docstring
    kv_ang = INERTIA_Z / timestep
    inertia = f"{INERTIA_Z!r} {INERTIA_Z!r} {INERTIA_Z!r}"
    px, py = PARKED_CENTER
    hx, hy = PARKED_HALF_SIZE
    walls = "\n".join(
        f'    <geom name="wall{i}" type="box" pos="{px} {py} 0" '
        f'size="{hx} {hy} {WALL_HALF_HEIGHT}" material="wall"/>'
        for i in range(num_wall_slots)
    )
    return f"""
<mujoco model="jaxnav_robot">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep!r}" gravity="0 0 0" integrator="Euler" solver="Newton"
          iterations="1" ls_iterations="4"/>
  <custom>
    <numeric name="max_geom_pairs" data="{MAX_GEOM_PAIRS}"/>
  </custom>
  <asset>
    <material name="wall" rgba="0.5 0.5 0.5 1"/>
    <material name="robot" rgba="0.2 0.4 0.8 1"/>
  </asset>
  <default>
    <geom condim="1" contype="1" conaffinity="1"/>
  </default>
  <worldbody>
{walls}
    <body name="robot" pos="0 0 0">
      <joint name="x" type="slide" axis="1 0 0" damping="0"/>
      <joint name="y" type="slide" axis="0 1 0" damping="0"/>
      <joint name="yaw" type="hinge" axis="0 0 1" damping="0"/>
      <inertial pos="0 0 0" mass="{MASS!r}" diaginertia="{inertia}"/>
      <geom name="{ROBOT_GEOM}" type="sphere" size="{radius!r}" material="robot"/>
    </body>
  </worldbody>
  <actuator>
    <velocity name="vx" joint="x" kv="{kv_lin!r}"/>
    <velocity name="vy" joint="y" kv="{kv_lin!r}"/>
    <velocity name="wz" joint="yaw" kv="{kv_ang!r}"/>
  </actuator>
</mujoco>
"""


def build_model(
    num_wall_slots: int,
    radius: float,
    arena_size: tuple[float, float],
    timestep: float = 0.02,
    substeps: int = 5,
) -> mujoco.MjModel:
    """The robot and ``num_wall_slots`` parked wall boxes as a MuJoCo model (see the module
    docstring for every setting). ``arena_size`` (metres) only checks that the parked slots lie
    outside it; ``substeps`` is validated here and used by ``MjxRobot``."""
    if num_wall_slots < 1:
        raise ValueError(f"num_wall_slots={num_wall_slots!r}: need at least 1")
    if not radius > 0 or not timestep > 0 or substeps < 1:
        raise ValueError(f"radius={radius!r}, timestep={timestep!r}, substeps={substeps!r}")
    if max(abs(c) for c in PARKED_CENTER) < 2 * max(arena_size) + 10:
        raise ValueError(f"parked slots at {PARKED_CENTER} are not outside arena {arena_size}")
    return mujoco.MjModel.from_xml_string(_xml(num_wall_slots, radius, timestep))


class MjxRobot:
    """The robot on MJX: the compiled-in model plus static sizes.

    ``with_walls`` makes a per-env model (vmap it over a batch of ``Walls``), ``init`` a state
    at a pose, ``step`` one control step of ``substeps * timestep`` seconds.
    """

    def __init__(
        self,
        num_wall_slots: int,
        radius: float,
        arena_size: tuple[float, float],
        timestep: float = 0.02,
        substeps: int = 5,
    ) -> None:
        self.num_wall_slots = num_wall_slots
        self.radius = float(radius)
        self.arena_size = arena_size
        self.timestep = float(timestep)
        self.substeps = int(substeps)
        self.dt = self.timestep * self.substeps
        self.mj_model = build_model(num_wall_slots, radius, arena_size, timestep, substeps)
        self.model: mjx.Model = mjx.put_model(self.mj_model, impl="jax")
        m = self.mj_model
        self.robot_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, ROBOT_GEOM)
        self.wall_geoms = np.array(
            [
                mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"wall{i}")
                for i in range(num_wall_slots)
            ]
        )

    def with_walls(self, walls: Walls, model: mjx.Model | None = None) -> mjx.Model:
        """``model`` (default the compiled-in one) with the wall slots set from one env's
        ``walls`` (``center[W, 2]``, ``half_size[W, 2]``, ``active[W]``). Inactive slots are put
        at ``PARKED_CENTER`` with ``PARKED_HALF_SIZE`` whatever their stored values, so they can
        neither collide nor win the broad phase. Traceable; ``batch_with_walls`` vmaps it over
        envs, batching only ``geom_pos``, ``geom_size`` and ``geom_rbound``."""
        model = self.model if model is None else model
        if walls.center.shape[-2] != self.num_wall_slots:
            raise ValueError(
                f"walls have {walls.center.shape[-2]} slots, model {self.num_wall_slots}"
            )
        active = jnp.asarray(walls.active, bool)[:, None]
        center = jnp.where(active, walls.center, jnp.asarray(PARKED_CENTER, jnp.float32))
        half = jnp.where(active, walls.half_size, jnp.asarray(PARKED_HALF_SIZE, jnp.float32))
        w = jnp.asarray(self.wall_geoms)
        z = jnp.zeros((self.num_wall_slots, 1), jnp.float32)
        hz = jnp.full((self.num_wall_slots, 1), WALL_HALF_HEIGHT, jnp.float32)
        size = jnp.concatenate([half, hz], axis=-1)
        geom_pos = model.geom_pos.at[w].set(jnp.concatenate([center, z], axis=-1))
        geom_size = model.geom_size.at[w].set(size)
        # the broad phase ranks pairs by bounding spheres: radius of the box's corners
        geom_rbound = model.geom_rbound.at[w].set(jnp.linalg.norm(size, axis=-1))
        return model.replace(geom_pos=geom_pos, geom_size=geom_size, geom_rbound=geom_rbound)

    def with_radius(self, model: mjx.Model, radius: jax.Array) -> mjx.Model:
        """``model`` with the robot's sphere of ``radius`` metres (a per-episode radius; its
        bounding sphere too, which the broad phase ranks pairs by). Traceable; under ``vmap``
        ``geom_size`` and ``geom_rbound`` become batched, as in ``with_walls``."""
        r = jnp.asarray(radius, jnp.float32)
        return model.replace(
            geom_size=model.geom_size.at[self.robot_geom].set(jnp.stack([r, r, r])),
            geom_rbound=model.geom_rbound.at[self.robot_geom].set(r),
        )

    @property
    def model_axes(self) -> mjx.Model:
        """``in_axes`` / ``out_axes`` for a model batched by ``with_walls``: 0 on ``geom_pos``,
        ``geom_size`` and ``geom_rbound``, None (shared) on everything else, so a batch of
        envs stores only its walls, not E copies of the model."""
        axes = jax.tree.map(lambda _: None, self.model)
        return axes.replace(geom_pos=0, geom_size=0, geom_rbound=0)

    def batch_with_walls(self, walls: Walls) -> mjx.Model:
        """A model batched over envs (axes ``model_axes``) from ``walls`` with a leading env
        axis (``center[E, W, 2]``); vmap ``init``/``step`` with ``in_axes=(robot.model_axes,
        0, ...)``."""
        return jax.vmap(self.with_walls, out_axes=self.model_axes)(walls)

    def init(self, model: mjx.Model, pose: jax.Array, forward: bool = True) -> mjx.Data:
        """State at ``pose = (x, y, theta)`` at rest, with positions and contacts computed
        (``forward=False`` leaves them out: ``step`` computes them first anyway, so an env that
        starts every control step from its pose saves one collision pass)."""
        pose = jnp.asarray(pose, jnp.float32)
        data = mjx.make_data(model)
        data = data.replace(qpos=pose.at[2].set(wrap_angle(pose[2])), qvel=jnp.zeros(3))
        return mjx.forward(model, data) if forward else data

    def pose(self, data: mjx.Data) -> jax.Array:
        """``float32[3]`` (x, y, theta) with theta wrapped to (-pi, pi]."""
        return data.qpos.at[2].set(wrap_angle(data.qpos[2]))

    def step(
        self, model: mjx.Model, data: mjx.Data, v: jax.Array, omega: jax.Array
    ) -> tuple[mjx.Data, jax.Array, jax.Array, jax.Array]:
        """One control step: ``substeps`` ``mjx.step`` calls with ``(v, omega)`` held.

        Returns ``(data, pose, collided, penetration)``: ``collided`` is whether the robot
        overlapped a wall (contact distance < 0) at any of the ``substeps + 1`` poses (the
        start, every substep's end), ``penetration`` the deepest such overlap (metres, 0
        without contact); ``pose`` is the final (x, y, theta), theta in (-pi, pi].
        """
        v = jnp.asarray(v, jnp.float32)
        omega = jnp.asarray(omega, jnp.float32)
        half_turn = 0.5 * omega * self.timestep

        def substep(_: int, carry: tuple[mjx.Data, jax.Array]) -> tuple[mjx.Data, jax.Array]:
            d, min_dist = carry
            # The mid-substep heading: with deadbeat gains the yaw moves omega * dt this
            # substep, so this heading makes the position follow the exact unicycle chord.
            th = d.qpos[2] + half_turn
            d = d.replace(ctrl=jnp.stack([v * jnp.cos(th), v * jnp.sin(th), omega]))
            d = mjx.step(model, d)
            return d, jnp.minimum(min_dist, self._min_contact_dist(d))

        data, min_dist = jax.lax.fori_loop(
            0, self.substeps, substep, (data, jnp.asarray(jnp.inf, jnp.float32))
        )
        # mjx.step collides *before* integrating, so the loop saw the poses at the start of
        # each substep; one more kinematics + collision pass covers the final pose (and leaves
        # its contacts in data); measured at 0-15% of the step's time on CPU. The yaw is
        # wrapped in the state too, so float32 angles never grow with many turns.
        pose = self.pose(data)
        data = mjx.collision(model, mjx.kinematics(model, data.replace(qpos=pose)))
        min_dist = jnp.minimum(min_dist, self._min_contact_dist(data))
        return data, pose, min_dist < 0.0, jnp.maximum(-min_dist, 0.0)

    def contact_penetration(self, data: mjx.Data) -> jax.Array:
        """Deepest robot-wall overlap (metres, 0 without contact) among ``data``'s contacts,
        which after ``init`` or ``step`` are those of its current pose."""
        return jnp.maximum(-self._min_contact_dist(data), 0.0)

    def _min_contact_dist(self, data: mjx.Data) -> jax.Array:
        """Smallest signed distance over the contact slots (every slot pairs the robot with a
        wall: walls are all on the world body, which does not collide with itself; MJX
        reports 1.0 for pairs far apart). Contacts live in the JAX implementation's part of
        Data in MJX 3.17 (``data._impl.contact``)."""
        return jnp.min(data._impl.contact.dist, initial=jnp.inf)
