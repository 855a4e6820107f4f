"""A collision monitor from the robot's own lidar, for any robot policy with one.

A move (forward, backward) is blocked when a lidar return of the newest frame lies in the strip
the robot's disc sweeps over one control period; the policy then takes the best of the moves
left. Turning in place is never blocked: a disc turns within itself. Between two neighbouring
beams that both hit, a wall's right-angled corner lies in the disc whose diameter joins the two
returns (Thales), so a move is also blocked where such a disc reaches into its strip.

One implementation for numpy (deployment, ``Policy.act(obs, policy.shield)``) and jax.numpy
(evaluation, ``python -m jaxnav.evaluate --policy shielded``): pass ``xp``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np


@dataclasses.dataclass(frozen=True)
class Shield:
    """What the monitor reads from an observation, taken from a policy's metadata."""

    laser_index: tuple[int, ...]  # observation indices of the newest frame's beams
    angles: tuple[float, ...]  # each beam's angle from the heading (radians, left positive)
    laser_metres: tuple[float, ...]  # metres per observation unit of each beam
    radius_index: int | None  # the observation's robot radius, if it has one
    radius: float  # metres, where the observation has none
    reach: tuple[float, ...]  # metres each action moves the centre in one period (signed)

    @classmethod
    def from_layouts(
        cls, observation: dict[str, Any], actions: list[dict[str, Any]], sensors: dict[str, Any]
    ) -> Shield:
        """The monitor of a policy with these layouts (``jaxnav.export.policy_metadata``'s
        ``observation``, ``actions`` and ``sensors``); ``ValueError`` (one line) for a policy
        without lidar."""
        if not sensors or "control_period_s" not in sensors:
            raise ValueError("a shield needs a robot policy with lidar (this one has none)")
        entries = observation["entries"]
        newest = max(e["frame"] for e in entries)
        lasers = [e for e in entries if e["frame"] == newest and e["name"] == "laser"]
        radius = [
            e["index"] for e in entries if e["frame"] == newest and e["name"] == "robot_radius"
        ]
        dt = float(sensors["control_period_s"])
        return cls(
            laser_index=tuple(int(e["index"]) for e in lasers),
            angles=tuple(float(e["angle_rad"]) for e in lasers),
            laser_metres=tuple(1.0 / float(e["scale"]) for e in lasers),
            radius_index=int(radius[0]) if radius else None,
            radius=float(sensors["robot_radius_m"]),
            reach=tuple(float(a["v_mps"]) * dt for a in actions),
        )

    @classmethod
    def from_metadata(cls, metadata: dict[str, Any]) -> Shield:
        """The monitor of an exported policy (its ``metadata``)."""
        return cls.from_layouts(metadata["observation"], metadata["actions"], metadata["sensors"])

    def blocked(self, obs: Any, xp: Any = np, speed_scale: Any = 1.0) -> Any:
        """bool [..., num_actions]: the moves whose sweep holds a lidar return of ``obs``, for
        speeds ``speed_scale`` times the layouts'."""
        rho = obs[..., list(self.laser_index)] * xp.asarray(self.laser_metres, obs.dtype)
        if self.radius_index is None:
            radius = xp.full(obs.shape[:-1] + (1,), self.radius, obs.dtype)
        else:
            radius = obs[..., self.radius_index : self.radius_index + 1]
        angles = xp.asarray(self.angles, obs.dtype)
        x, y = rho * xp.cos(angles), rho * xp.sin(angles)
        hit = rho < 0.999 * xp.asarray(self.laser_metres, obs.dtype)  # the range: no return
        i, j = self.neighbours()
        pair = hit[..., i] & hit[..., j] & self.bends(x, y, hit, xp)
        mx, my = (x[..., i] + x[..., j]) / 2, (y[..., i] + y[..., j]) / 2
        half = xp.sqrt((x[..., i] - x[..., j]) ** 2 + (y[..., i] - y[..., j]) ** 2) / 2
        # both faces of one corner: returns about as far (a wall's end seen against a far wall
        # is not modelled)
        spacing = np.abs(np.asarray(self.angles)[j] - np.asarray(self.angles)[i])
        spacing = np.minimum(spacing, 2 * np.pi - spacing)
        near = xp.minimum(rho[..., i], rho[..., j])
        pair = pair & (half <= near * xp.asarray(np.sin(spacing), obs.dtype))
        moves = []
        for reach in self.reach:
            if reach == 0.0:  # turning in place
                moves.append(xp.zeros(obs.shape[:-1], bool))
                continue
            sign, length = (1.0 if reach > 0 else -1.0), abs(reach) * speed_scale + radius
            point = (xp.abs(y) < radius) & (sign * x > 0) & (sign * x < length)
            corner = pair & (xp.abs(my) < radius + half) & (sign * mx + half > 0)
            corner = corner & (sign * mx - half < length)
            moves.append(xp.any(point, axis=-1) | xp.any(corner, axis=-1))
        return xp.stack(moves, axis=-1)

    def neighbours(self) -> tuple[np.ndarray, np.ndarray]:
        """``(i, j)``: the beams of each pair of neighbours, j = i + 1, and the last with the
        first where the beams go all around."""
        n = len(self.angles)
        i = np.arange(n if self.all_around else n - 1)
        return i, (i + 1) % n

    def bends(self, x: Any, y: Any, hit: Any, xp: Any = np) -> Any:
        """bool [..., pairs]: whether the returns of each pair of ``neighbours`` may have a
        corner between them: neither of them lies on a straight line with its other
        neighbour's return (three returns in a line are one straight wall)."""
        n = len(self.angles)
        idx = np.arange(n)
        prv, nxt = (idx - 1) % n, (idx + 1) % n

        def straight(a: Any, b: Any, c: Any) -> Any:  # b on the line a-c, within 1 cm
            cross = (x[..., c] - x[..., a]) * (y[..., b] - y[..., a]) - (
                y[..., c] - y[..., a]
            ) * (x[..., b] - x[..., a])
            length = xp.sqrt((x[..., c] - x[..., a]) ** 2 + (y[..., c] - y[..., a]) ** 2)
            ok = hit[..., a] & hit[..., b] & hit[..., c]
            return ok & (xp.abs(cross) < 0.01 * xp.maximum(length, 1e-6))

        line = straight(prv, idx, nxt)  # return i on one line with both its neighbours
        if not self.all_around:  # the end beams have one neighbour: never in a line
            line = line & xp.asarray((idx > 0) & (idx < n - 1))
        i, j = self.neighbours()
        return ~line[..., i] & ~line[..., j]

    @property
    def all_around(self) -> bool:
        """Whether the beams cover 360 degrees at an even spacing (the last neighbours the
        first)."""
        gaps = np.diff(np.asarray(self.angles))
        return len(gaps) > 0 and bool(np.isclose(2 * np.pi - np.sum(gaps), gaps[0]))

    def act(self, q: Any, obs: Any, xp: Any = np) -> Any:
        """The first of the largest Q-values among the moves not blocked (turns never are)."""
        return xp.argmax(xp.where(self.blocked(obs, xp), -xp.inf, q), axis=-1)
