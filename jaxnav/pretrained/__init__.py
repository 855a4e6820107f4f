"""Pretrained policies shipped with jaxnav: ``jaxnav.pretrained.load(name)``.

Each is an npz written by ``python -m jaxnav.export`` (weights and metadata: observation
layout, actions, sensors, env id and kwargs) with an entry in ``manifest.json``: the env, the
commands that made it, and its success measured on fresh episodes (episodes, seed). ``load``
returns a ``jaxnav.deploy.policy.Policy`` (numpy, no JAX); ``python -m jaxnav.evaluate
--pretrained NAME`` and ``python -m jaxnav.render --pretrained NAME`` run one in the
simulator.

Adding one (e.g. a robot policy trained on a GPU): export it, copy the npz here, and let
``python -m jaxnav.pretrained add NAME FILE.npz --command "..."`` measure its success on
fresh episodes and write its manifest entry (``tests/test_pretrained.py`` then checks every
entry against fresh episodes on each test run).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from jaxnav.deploy.policy import Policy

HERE = Path(__file__).resolve().parent
MANIFEST = HERE / "manifest.json"


def manifest() -> dict[str, dict[str, Any]]:
    """Every shipped policy's entry, by name."""
    return json.loads(MANIFEST.read_text())["policies"]


def names() -> list[str]:
    return sorted(manifest())


def entry(name: str) -> dict[str, Any]:
    """``name``'s manifest entry; ``ValueError`` naming the shipped policies if none."""
    policies = manifest()
    if name not in policies:
        raise ValueError(f"--pretrained {name}: no such policy; shipped: {', '.join(names())}")
    return policies[name]


def path(name: str) -> Path:
    """The npz file of ``name``."""
    return HERE / entry(name)["file"]


def sha256(file: Path) -> str:
    return hashlib.sha256(file.read_bytes()).hexdigest()


def load(name: str) -> Policy:
    """The shipped policy ``name`` (``names()`` lists them), checked against its manifest
    entry's sha256."""
    e, file = entry(name), path(name)
    if e.get("sha256") and sha256(file) != e["sha256"]:
        raise ValueError(f"{file}: sha256 differs from the manifest's; the file was changed")
    return Policy.load(file)


def load_source(source: str, what: str) -> Policy:
    """A shipped policy by name, or an exported npz file by path (``source``); ``ValueError``
    naming ``what`` (the flag or field that gave it) if it is neither."""
    if os.path.exists(source) or source.endswith(".npz"):
        if not os.path.isfile(source):
            raise ValueError(f"{what}: no such policy file")
        return Policy.load(source)
    if source in names():
        return load(source)
    raise ValueError(f"{what}: neither an npz file nor a shipped policy ({', '.join(names())})")
