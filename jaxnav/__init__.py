"""jaxnav: mobile-robot navigation with deep RL, end to end in JAX.

The names below are imported on first use (PEP 562), not with the package: ``jaxnav.deploy``
runs an exported policy on a robot with numpy alone, and importing it must not start JAX.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import signal
import sys
import threading
from typing import TYPE_CHECKING, Any

from jaxnav.version import __version__ as __version__  # the package's version, re-exported

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


def _command_of(orig_argv: list[str]) -> str | None:
    """The jaxnav module a ``python [options] -m MODULE`` command line runs, else None."""
    for i, arg in enumerate(orig_argv[1:], 1):
        module = orig_argv[i + 1] if arg == "-m" and i + 1 < len(orig_argv) else None
        if arg.startswith("-m") and arg != "-m":
            module = arg[2:]
        if module is not None:
            return module.removesuffix(".__main__") if module.startswith("jaxnav") else None
        if not arg.startswith("-"):
            return None
    return None


def _stopped_while_starting(signum: int, frame: Any) -> None:
    if getattr(sys.modules.get("__main__"), "main", None) is not None:
        signal.default_int_handler(signum, frame)  # the command runs: its KeyboardInterrupt
    # still importing: nothing written yet, and an exception could land in a gc callback
    os.write(2, f"{_COMMAND}: stopped by {signal.Signals(signum).name}\n".encode())
    os._exit(128 + signum)


# ``python -m jaxnav.<command>`` imports this package first ("-m" is sys.argv[0] until the
# command's module runs): Ctrl-C while JAX imports, before the command's ``main`` is defined,
# is one line and exit 130, not a traceback
_COMMAND = _command_of(getattr(sys, "orig_argv", []))
if sys.argv[:1] == ["-m"] and _COMMAND and threading.current_thread() is threading.main_thread():
    signal.signal(signal.SIGINT, _stopped_while_starting)


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
