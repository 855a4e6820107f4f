"""An exported jaxnav policy in plain numpy: load the npz, compute Q-values, act greedily.

Needs numpy and the standard library only (no JAX), so it runs on a robot's computer; the
file can be copied there on its own. ``python -m jaxnav.export RUN --format npz`` writes the
npz: the network's arrays under the names below and its metadata as JSON in ``metadata``
(a 0-d string array, readable without pickle)::

    dense{i}_kernel [in, out], dense{i}_bias [out]       hidden layer i (i = 0, 1, ...)
    norm{i}_scale [out], norm{i}_bias [out]              its LayerNorm, if the network has one
    head_kernel, head_bias                               Q-values (without dueling heads)
    value_kernel [h, 1], value_bias [1]                  dueling: Q = V + (A - mean_a A)
    advantage_kernel [h, A], advantage_bias [A]

Forward pass, as ``jaxnav.agents.dqn.QNetwork`` computes it: the observation as float32
(values the metadata's ``network.onehot_sizes`` marks as categories one-hot encoded first),
then per hidden layer ``x @ kernel + bias``, LayerNorm (``(x - mean) / sqrt(var + eps) * scale
+ bias``) where present, ReLU; then the head(s).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

FORMAT = "jaxnav-policy"
FORMAT_VERSION = 1


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


def forward(arrays: dict[str, np.ndarray], network: dict[str, Any], obs: np.ndarray) -> np.ndarray:
    """Q-values ``float32[..., num_actions]`` of observations ``obs[..., obs_size]`` for the
    network described by ``network`` (the metadata's ``"network"``) with weights ``arrays``."""
    obs = np.asarray(obs)
    if obs.shape[-1] != network["obs_size"]:
        raise ValueError(
            f"observation of {obs.shape[-1]} values; the policy reads {network['obs_size']}"
        )
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
    if not network["dueling"]:
        return (x @ arrays["head_kernel"] + arrays["head_bias"]).astype(np.float32)
    value = x @ arrays["value_kernel"] + arrays["value_bias"]
    advantage = x @ arrays["advantage_kernel"] + arrays["advantage_bias"]
    return (value + advantage - advantage.mean(axis=-1, keepdims=True)).astype(np.float32)


class Policy:
    """A loaded policy: ``policy.act(obs)`` is the greedy action (an int for one observation,
    an array for a batch), ``policy.q_values(obs)`` the Q-values, ``policy.metadata`` what
    ``jaxnav.export`` recorded (observation layout, actions, sensors, env id and kwargs)."""

    def __init__(self, arrays: dict[str, np.ndarray], metadata: dict[str, Any]):
        if metadata.get("format") != FORMAT:
            raise ValueError(f"not a jaxnav policy (format {metadata.get('format')!r})")
        if metadata.get("format_version", 0) > FORMAT_VERSION:
            raise ValueError(
                f"policy format version {metadata['format_version']} is newer than this "
                f"reader's {FORMAT_VERSION}; update jaxnav"
            )
        self.arrays = {k: np.asarray(v, np.float32) for k, v in arrays.items()}
        self.metadata = metadata
        self.network = metadata["network"]

    @classmethod
    def load(cls, path: str | os.PathLike) -> Policy:
        """The policy in the npz file ``path`` (``python -m jaxnav.export --format npz``)."""
        with np.load(path, allow_pickle=False) as f:
            if "metadata" not in f.files:
                raise ValueError(f"{path}: not a jaxnav policy (no metadata)")
            metadata = json.loads(str(f["metadata"]))
            arrays = {k: f[k] for k in f.files if k != "metadata"}
        return cls(arrays, metadata)

    @property
    def obs_size(self) -> int:
        return int(self.network["obs_size"])

    @property
    def action_names(self) -> list[str]:
        return [a["name"] for a in self.metadata["actions"]]

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        return forward(self.arrays, self.network, obs)

    def act(self, obs: np.ndarray) -> Any:
        """The greedy action: the first of the largest Q-values, as ``jnp.argmax`` picks."""
        action = np.argmax(self.q_values(obs), axis=-1)
        return int(action) if action.ndim == 0 else action
