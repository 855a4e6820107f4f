"""jaxnav: mobile-robot navigation with deep RL, end to end in JAX.

The names below are imported on first use (PEP 562), not with the package: ``jaxnav.deploy``
runs an exported policy on a robot with numpy alone, and importing it must not start JAX.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"
__all__ = ["Environment", "EnvParams", "EnvState", "env_config", "make", "registered_envs"]

_HOME = {
    "Environment": "jaxnav.environment",
    "EnvParams": "jaxnav.environment",
    "EnvState": "jaxnav.environment",
    "env_config": "jaxnav.registration",
    "make": "jaxnav.registration",
    "registered_envs": "jaxnav.registration",
}

if TYPE_CHECKING:
    from jaxnav.environment import Environment, EnvParams, EnvState
    from jaxnav.registration import env_config, make, registered_envs


def __getattr__(name: str) -> Any:
    if name in _HOME:
        value = getattr(importlib.import_module(_HOME[name]), name)
        globals()[name] = value  # once: later look-ups are plain attributes
        return value
    if not name.startswith("__") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        # ``jaxnav.envs...`` after a bare ``import jaxnav``, as when the package imported
        # its environments eagerly
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module 'jaxnav' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_HOME])
