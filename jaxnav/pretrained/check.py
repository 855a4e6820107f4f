"""Measuring a policy's success in the simulator, for the manifest and its test (JAX)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from jaxnav.deploy.policy import Policy
from jaxnav.evaluate import evaluate_seeds
from jaxnav.export import to_trainer
from jaxnav.pretrained import HERE, MANIFEST, sha256
from jaxnav.safe_io import atomic_output, remove_quietly, write_text

MEASURED = ("success_rate", "collision_rate", "timeout_rate", "mean_steps", "mean_path_ratio")


def measure(policy: Policy, episodes: int, seed: int) -> dict[str, Any]:
    """The greedy policy's outcomes on ``episodes`` fresh episodes of its env (the starts and
    goals of ``seed``, layouts round-robin), as ``python -m jaxnav.evaluate`` measures them."""
    trainer, params = to_trainer(policy)
    row = evaluate_seeds(trainer, params, episodes, seed)[0]
    return {"episodes": episodes, "seed": seed, **{k: row[k] for k in MEASURED}}


def add_entry(
    name: str, file: Path, commands: list[str], episodes: int, seed: int, note: str = ""
) -> dict[str, Any]:
    """Measure the policy in ``file``, then copy it into the pretrained folder as NAME.npz and
    write its manifest entry (replacing any of that name); returns the entry. Nothing is
    copied or written where loading or measuring fails."""
    policy = Policy.load(file)
    meta = policy.metadata
    measured = measure(policy, episodes, seed)
    target = HERE / f"{name}.npz"
    new = not target.exists()
    if Path(file).resolve() != target:
        with atomic_output(target) as tmp:  # whole or not at all
            shutil.copyfile(file, tmp)
    entry = {
        "file": target.name,
        "sha256": sha256(target),
        "env_id": meta["env_id"],
        "env_kwargs": meta["env_kwargs"],
        "network": "-".join(map(str, meta["network"]["hidden_sizes"])),
        "commands": commands,
        "measured": measured,
        "measured_with": f"python -m jaxnav.evaluate --pretrained {name} --episodes {episodes} "
        f"--seed {seed}",
        "note": note,
    }
    doc = json.loads(MANIFEST.read_text()) if MANIFEST.exists() else {"policies": {}}
    doc["policies"][name] = entry
    try:
        write_text(MANIFEST, json.dumps(doc, indent=2) + "\n")
    except BaseException:
        if new:  # a policy without its manifest entry is not shipped
            remove_quietly(target)
        raise
    return entry
