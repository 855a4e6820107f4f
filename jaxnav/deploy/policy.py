"""An exported jaxnav policy in plain numpy: load the npz, compute Q-values, act greedily.

Needs numpy and the standard library only (no JAX), so it runs on a robot's computer; the
file can be copied there on its own. ``python -m jaxnav.export RUN --format npz`` writes the
npz: the network's arrays under the names below and its metadata as JSON in ``metadata``
(a 0-d string array, readable without pickle) and the SHA-256 of every other array as JSON in
``checksum`` (``array_checksums``; files exported without one load unchecked)::

    dense{i}_kernel [in, out], dense{i}_bias [out]       hidden layer i (i = 0, 1, ...)
    norm{i}_scale [out], norm{i}_bias [out]              its LayerNorm, if the network has one
    gru_{g}_kernel [in or H, H], gru_{g}_bias [H]        with memory (``network.memory`` = H):
                                                         the GRU cell's gates g = ir, iz, in
                                                         (from x, with biases), hr, hz (from
                                                         the state, none), hn (with one)
    head_kernel, head_bias                               Q-values (without dueling heads)
    value_kernel [h, 1], value_bias [1]                  dueling: Q = V + (A - mean_a A)
    advantage_kernel [h, A], advantage_bias [A]

Forward pass, as ``jaxnav.agents.dqn.QNetwork`` computes it: the observation as float32
(values the metadata's ``network.onehot_sizes`` marks as categories one-hot encoded first),
then per hidden layer ``x @ kernel + bias``, LayerNorm (``(x - mean) / sqrt(var + eps) * scale
+ bias``) where present, ReLU; then the head(s).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
import sys
import zipfile
import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxnav.deploy.shield import Shield

FORMAT = "jaxnav-policy"
FORMAT_VERSION = 2  # 2: a network with memory (feed-forward ones are still written as 1)
# the GRU cell's weights by gate: whether it has a bias (flax's GRUCell, input then state)
GRU_GATES = {"ir": True, "iz": True, "in": True, "hr": False, "hz": False, "hn": True}
CHECKSUM_KEY = "checksum"  # the npz array (and ONNX metadata_props key) of the checksums


def array_checksums(arrays: dict[str, np.ndarray]) -> dict[str, str]:
    """The SHA-256 of each array (its dtype, shape and bytes), by name: written with an
    exported policy, compared by ``verify_checksums`` when it is loaded."""
    sums = {}
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        digest = hashlib.sha256(f"{a.dtype.str} {a.shape} ".encode())
        digest.update(a.tobytes())
        sums[name] = digest.hexdigest()
    return sums


def verify_checksums(path: str | os.PathLike, arrays: dict[str, np.ndarray], text: str) -> None:
    """``ValueError`` (one line naming ``path`` and the array) unless ``arrays`` match the
    checksums ``text`` (``array_checksums`` as JSON) written with them."""
    try:
        written = json.loads(text)
    except ValueError:
        written = None
    if not isinstance(written, dict):
        raise ValueError(f"{path}: damaged policy file (its checksums are unreadable)")
    got = array_checksums(arrays)
    for name in sorted(set(written) | set(got)):
        if written.get(name) != got.get(name):
            what = "differs from its checksum"
            if name not in got or name not in written:
                what = "is missing" if name not in got else "is not in its checksums"
            raise ValueError(
                f"{path}: damaged policy file (array {name!r} {what}); export the policy again"
            )


def expand_onehot(obs: np.ndarray, onehot_sizes: Sequence[int]) -> np.ndarray:
    """``obs[..., i]`` one-hot encoded into ``onehot_sizes[i]`` columns (kept as one number
    where that is 0), as ``jaxnav.agents.dqn.expand_onehot``: values truncated to integers, a
    value outside ``[0, n)`` encodes as all zeros."""
    parts = []
    for i, n in enumerate(onehot_sizes):
        column = obs[..., i]
        if n:
            index = column.astype(np.int32)
            parts.append((index[..., None] == np.arange(n, dtype=np.int32)).astype(np.float32))
        else:
            parts.append(column[..., None].astype(np.float32))
    return np.concatenate(parts, axis=-1)


def forward(
    arrays: dict[str, np.ndarray],
    network: dict[str, Any],
    obs: np.ndarray,
    hidden: np.ndarray | None = None,
) -> np.ndarray:
    """Q-values ``float32[..., num_actions]`` of observations ``obs[..., obs_size]`` for the
    network described by ``network`` (the metadata's ``"network"``) with weights ``arrays``;
    with memory, read with the state ``hidden`` (``step``)."""
    return step(arrays, network, obs, hidden)[0]


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))  # no overflow for large negative x


def step(
    arrays: dict[str, np.ndarray],
    network: dict[str, Any],
    obs: np.ndarray,
    hidden: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """``(Q-values, the next state)`` of observations ``obs[..., obs_size]``: a network with
    memory reads the state ``hidden[..., memory]`` of the previous step (None: zeros, an
    episode's start); one without returns None for the state."""
    try:
        obs = np.asarray(obs)
        if obs.dtype.kind not in "biuf":  # complex, strings, objects: no silent conversion
            raise TypeError
        obs = obs.astype(np.float64)
    except (TypeError, ValueError):
        raise ValueError("observation: must be real numbers") from None
    if obs.ndim == 0 or obs.shape[-1] != network["obs_size"]:
        raise ValueError(
            f"observation of shape {obs.shape}; the policy reads {network['obs_size']} values"
        )
    bad = ~(np.abs(obs) <= np.finfo(np.float32).max)  # NaN, inf, or inf once float32
    if bad.any():  # no action from a NaN or an infinite input
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        index = ", ".join(map(str, where))
        value = float(obs[where])
        why = "not finite" if not math.isfinite(value) else "beyond float32"
        raise ValueError(f"observation[{index}]={value}: {why}")
    onehot = network.get("onehot_sizes")
    x = obs.astype(np.float32) if onehot is None else expand_onehot(obs, onehot)
    eps = np.float32(network.get("layer_norm_epsilon", 1e-6))
    for i in range(len(network["hidden_sizes"])):
        x = x @ arrays[f"dense{i}_kernel"] + arrays[f"dense{i}_bias"]
        if network["layer_norm"]:
            mean = x.mean(axis=-1, keepdims=True)
            var = np.square(x - mean).mean(axis=-1, keepdims=True)
            x = (x - mean) / np.sqrt(var + eps) * arrays[f"norm{i}_scale"] + arrays[f"norm{i}_bias"]
        x = np.maximum(x, 0).astype(np.float32)
    memory = int(network.get("memory", 0))
    if memory:
        h = np.zeros((*x.shape[:-1], memory), np.float32) if hidden is None else hidden
        if h.shape != (*x.shape[:-1], memory):
            raise ValueError(
                f"state of shape {h.shape} for observations of shape {obs.shape}; reset() the "
                "policy where episodes start"
            )
        gate = {
            g: (x if g[0] == "i" else h) @ arrays[f"gru_{g}_kernel"]
            + (arrays[f"gru_{g}_bias"] if biased else 0)
            for g, biased in GRU_GATES.items()
        }
        r = _sigmoid(gate["ir"] + gate["hr"])
        z = _sigmoid(gate["iz"] + gate["hz"])
        n = np.tanh(gate["in"] + r * gate["hn"])
        x = hidden = ((1.0 - z) * n + z * h).astype(np.float32)
    else:
        hidden = None
    if not network["dueling"]:
        return (x @ arrays["head_kernel"] + arrays["head_bias"]).astype(np.float32), hidden
    value = x @ arrays["value_kernel"] + arrays["value_bias"]
    advantage = x @ arrays["advantage_kernel"] + arrays["advantage_bias"]
    q = value + advantage - advantage.mean(axis=-1, keepdims=True)
    return q.astype(np.float32), hidden


def _scale(value: float) -> str:
    """A scale as a reader wants it: 1/3.5 rather than 0.2857142857142857."""
    if value == 1:
        return "1"
    inverse = 1 / value
    return f"1/{inverse:g}" if abs(inverse - round(inverse, 4)) < 1e-9 else f"{value:.6g}"


def describe(metadata: dict[str, Any]) -> str:
    """A policy's metadata as text: env, actions, sensors and a markdown table of one frame of
    its observation (consecutive entries of one name on one row)."""
    obs, net = metadata["observation"], metadata["network"]
    lines = [
        f"env: {metadata['env_id']} {json.dumps(metadata['env_kwargs'])}",
        f"network: {net['obs_size']} inputs -> {'-'.join(map(str, net['hidden_sizes']))} -> "
        f"{net['num_actions']} Q-values (dueling {net['dueling']}, layer norm "
        f"{net['layer_norm']}"
        + (f", a GRU of {net['memory']} units" if net.get("memory") else "")
        + ")",
        "actions: "
        + ", ".join(
            f"{a['index']} {a['name']}"
            + (f" (v {a['v_mps']:g} m/s, omega {a['omega_radps']:g} rad/s)" if "v_mps" in a else "")
            for a in metadata["actions"]
        ),
    ]
    sensors = metadata.get("sensors")
    if sensors:
        period = sensors["control_period_s"]
        lines.append(
            f"lidar: {sensors['num_lasers']} beams over {sensors['laser_fov_deg']:g} degrees, "
            f"read to {sensors['laser_range_m']:g} m; control period {period:g} s; "
            f"frames {sensors['frames']}"
        )
    frames = obs.get("frames", 1)
    entries = [e for e in obs["entries"] if e.get("frame", 0) == 0]
    stacked = f" = {frames} frames of {obs['frame_size']}, oldest first" if frames > 1 else ""
    lines += [
        "",
        f"observation: {obs['size']} values{stacked}",
        "",
        "| index | name | raw quantity | scale | clip |",
        "|---|---|---|---|---|",
    ]
    quantities = obs.get("quantities", {})
    i = 0
    while i < len(entries):
        e = entries[i]
        j = i
        while j + 1 < len(entries) and entries[j + 1]["name"] == e["name"]:
            j += 1
        index = f"{i}" if i == j else f"{i}-{j}"
        what = quantities.get(e["name"], "")
        if e["name"] == "laser":
            angles = [math.degrees(entries[k]["angle_rad"]) for k in range(i, j + 1)]
            ahead = min(range(len(angles)), key=lambda k: abs(angles[k]))
            step = f" every {angles[1] - angles[0]:g}" if len(angles) > 1 else ""
            what += (
                f"; beams at {angles[0]:g} .. {angles[-1]:g} degrees{step} from the heading "
                f"(counter-clockwise), index {i + ahead} straight ahead"
            )
        elif "categories" in e:
            what += f" ({e['categories']} categories, one-hot encoded by the network)"
        clip = "" if e["clip"] is None else f"[{e['clip'][0]:g}, {e['clip'][1]:g}]"
        lines.append(f"| {index} | {e['name']} | {what} | {_scale(e['scale'])} | {clip} |")
        i = j + 1
    return "\n".join(lines)


class Policy:
    """A loaded policy: ``policy.act(obs)`` is the greedy action (an int for one observation,
    an array for a batch), ``policy.q_values(obs)`` the Q-values, ``policy.metadata`` what
    ``jaxnav.export`` recorded (observation layout, actions, sensors, env id and kwargs).

    A policy with memory (``policy.memory`` > 0) keeps its state (``policy.hidden``): call
    ``reset()`` at an episode's start (``reset(done)`` for the rows of a batch whose episode
    ended); each ``act`` reads it and advances it one step, ``q_values`` only reads it."""

    def __init__(self, arrays: dict[str, np.ndarray], metadata: dict[str, Any]):
        """``ValueError`` (one line) unless ``metadata`` and ``arrays`` make a network of
        this reader's format that computes Q-values."""
        if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
            got = metadata.get("format") if isinstance(metadata, dict) else None
            raise ValueError(f"not a jaxnav policy (format {got!r})")
        if metadata.get("format_version", 0) > FORMAT_VERSION:
            raise ValueError(
                f"policy format version {metadata['format_version']} is newer than this "
                f"reader's {FORMAT_VERSION}; update jaxnav"
            )
        self.arrays = {k: np.asarray(v, np.float32) for k, v in arrays.items()}
        self.metadata = metadata
        self.network = metadata.get("network")
        self.hidden: np.ndarray | None = None  # with memory: the state for the next step
        try:  # the weights a forward pass reads, in shapes that fit: not at the first act
            q = forward(self.arrays, self.network, np.zeros(int(self.network["obs_size"])))
        except (KeyError, TypeError, ValueError, IndexError) as e:
            raise ValueError(f"not a jaxnav policy (its network does not compute: {e!r})") from None
        if q.shape != (len(metadata.get("actions", ())),):
            raise ValueError(f"not a jaxnav policy ({q.shape[-1]} Q-values for its actions)")

    @classmethod
    def load(cls, path: str | os.PathLike) -> Policy:
        """The policy in the npz file ``path`` (``python -m jaxnav.export --format npz``);
        ``ValueError`` (one line naming the file) for a file that is not one, or is damaged
        or truncated (its arrays checked against the checksums written with them)."""
        if not stat.S_ISREG(os.stat(path).st_mode):  # reading a FIFO would block forever
            raise ValueError(f"{path}: not a jaxnav policy file (not a regular file)")
        with open(path, "rb") as f:
            if f.read(4) != b"PK\x03\x04":  # an npz is a zip archive
                raise ValueError(f"{path}: not a jaxnav policy file (not an npz archive)")
        try:
            with np.load(path, allow_pickle=False) as f:
                arrays = {k: f[k] for k in f.files}
        except (zipfile.BadZipFile, EOFError, zlib.error) as e:
            raise ValueError(f"{path}: truncated or damaged policy file ({e})") from None
        except ValueError as e:  # an object array
            raise ValueError(f"{path}: not a jaxnav policy file ({e})") from None
        checksums = arrays.pop(CHECKSUM_KEY, None)  # None: exported before checksums
        if checksums is not None:
            verify_checksums(path, arrays, str(checksums))
        try:
            metadata = json.loads(str(arrays.pop("metadata", "null")))
        except ValueError as e:
            raise ValueError(f"{path}: not a jaxnav policy file ({e})") from None
        if metadata is None:
            raise ValueError(f"{path}: not a jaxnav policy file (no metadata)")
        try:
            return cls(arrays, metadata)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None

    @property
    def obs_size(self) -> int:
        return int(self.network["obs_size"])

    @property
    def action_names(self) -> list[str]:
        return [a["name"] for a in self.metadata["actions"]]

    @property
    def memory(self) -> int:
        """Units of the network's GRU cell (0: no memory)."""
        return int(self.network.get("memory", 0))

    def reset(self, done: np.ndarray | None = None) -> None:
        """An episode's start: the state back to zeros, of every row or of the rows of a batch
        where ``done`` (bool [batch]) is true."""
        if done is None or self.hidden is None:
            self.hidden = None
        else:
            self.hidden = np.where(np.asarray(done, bool)[..., None], 0.0, self.hidden)
            self.hidden = self.hidden.astype(np.float32)

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        """The Q-values of ``obs``, with memory read with the current state (not advanced)."""
        return forward(self.arrays, self.network, obs, self.hidden)

    @property
    def shield(self) -> Shield:
        """The lidar collision monitor for this policy's robot (``jaxnav.deploy.shield``);
        ``ValueError`` (one line) for a policy without lidar."""
        return Shield.from_metadata(self.metadata)

    def act(self, obs: np.ndarray, shield: Shield | None = None) -> Any:
        """The greedy action: the first of the largest Q-values, as ``jnp.argmax`` picks; with
        memory the state advances to the one after ``obs``. With a ``shield`` (e.g.
        ``policy.shield``), the best of the moves it does not block."""
        q, hidden = step(self.arrays, self.network, obs, self.hidden)
        if self.memory:
            self.hidden = hidden
        if shield is not None:
            action = shield.act(q, np.asarray(obs, np.float32))
        else:
            action = np.argmax(q, axis=-1)
        return int(action) if action.ndim == 0 else action


def main(argv: list[str] | None = None) -> int:
    """``python -m jaxnav.deploy.policy POLICY.npz``: print what the policy reads and does."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m jaxnav.deploy.policy POLICY.npz", file=sys.stderr)
        return 2
    try:
        policy = Policy.load(args[0])
    except (OSError, ValueError, KeyError) as e:
        print(f"jaxnav.deploy.policy: error: {e}", file=sys.stderr)
        return 2
    print(describe(policy.metadata))
    return 0


if __name__ == "__main__":
    sys.exit(main())
