"""Optional metric sinks beside metrics.csv (which stays the record of a run): TensorBoard event
files (``--tensorboard``, through ``tensorboardX``: ``pip install -e ".[tensorboard]"``) and
Weights & Biases (``--wandb``, when ``wandb`` is installed).

A logger gets each logging interval's metrics (every seed, leading axis) with its env step;
it writes the mean over seeds as ``train/<metric>`` and, with several seeds, each seed's
value as ``seed<k>/<metric>``.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

INSTALL = {
    "tensorboardX": 'pip install -e ".[tensorboard]" (or pip install tensorboardX)',
    "wandb": "pip install wandb",
}


class MetricsLogger(Protocol):
    def log(self, metrics: Mapping[str, np.ndarray], step: int) -> None: ...

    def close(self) -> None: ...


def require(module: str, flag: str) -> Any:
    """``module`` imported; ``ValueError`` naming ``flag`` and the install command if it is
    not installed (checked before a run writes or compiles anything)."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ValueError(f"{flag}: {module} is not installed; {INSTALL[module]}") from None


def scalars(metrics: Mapping[str, np.ndarray], seeds: Sequence[int]) -> dict[str, float]:
    """``train/<metric>`` (mean over seeds) and, for several seeds, ``seed<k>/<metric>``."""
    out: dict[str, float] = {}
    for name, value in metrics.items():
        if name == "env_steps":
            continue
        v = np.asarray(value, np.float64).reshape(len(seeds), -1)[:, -1]
        out[f"train/{name}"] = float(np.mean(v))
        if len(seeds) > 1:
            out.update({f"seed{s}/{name}": float(x) for s, x in zip(seeds, v, strict=True)})
    return out


class TensorBoardLogger:
    """Event files in ``directory``, read by ``tensorboard --logdir``."""

    def __init__(self, directory: Path, seeds: Sequence[int]):
        writer = require("tensorboardX", "--tensorboard").SummaryWriter
        self.seeds = list(seeds)
        self.writer = writer(str(directory))

    def log(self, metrics: Mapping[str, np.ndarray], step: int) -> None:
        for tag, value in scalars(metrics, self.seeds).items():
            self.writer.add_scalar(tag, value, step)
        self.writer.flush()  # a killed run keeps what was logged

    def close(self) -> None:
        self.writer.close()


class WandbLogger:
    """One W&B run per training run, named after its output directory."""

    def __init__(self, name: str, config: dict[str, Any], directory: Path, seeds: Sequence[int]):
        self.wandb = require("wandb", "--wandb")
        self.seeds = list(seeds)
        self.run = self.wandb.init(project="jaxnav", name=name, config=config, dir=str(directory))

    def log(self, metrics: Mapping[str, np.ndarray], step: int) -> None:
        self.run.log(scalars(metrics, self.seeds), step=step)

    def close(self) -> None:
        self.run.finish()
