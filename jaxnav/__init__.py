"""jaxnav: mobile-robot navigation with deep RL, end to end in JAX.

The names below are imported on first use (PEP 562), not with the package: ``jaxnav.deploy``
runs an exported policy on a robot with numpy alone, and importing it must not start JAX.
"""

from __future__ import annotations

import contextlib
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


class Stopped(KeyboardInterrupt):
    """SIGINT or SIGTERM while a jaxnav command runs outside training's own handler: unwound
    like Ctrl-C (every output whole or absent), then exit 128 + ``signum``."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__(signum)
        self.signum = signum


def raise_stopped(signum: int, frame: Any) -> None:
    """A signal handler raising ``Stopped(signum)``."""
    raise Stopped(signum)


def _stopped_while_starting(signum: int, frame: Any) -> None:
    if getattr(sys.modules.get("__main__"), "main", None) is not None:
        raise Stopped(signum)  # the command runs: unwound, then ``_stopped_hook``
    # still importing: nothing written yet, and an exception could land in a gc callback
    os.write(2, f"{_COMMAND}: stopped by {signal.Signals(signum).name}\n".encode())
    os._exit(128 + signum)


def _stopped_hook(kind: type[BaseException], value: BaseException, tb: Any) -> None:
    """``sys.excepthook`` of a command: a signal's ``KeyboardInterrupt`` that reached the top
    (its outputs unwound) is one line and exit 128 + the signal, not a traceback."""
    if not isinstance(value, KeyboardInterrupt):
        return sys.__excepthook__(kind, value, tb)
    signum = getattr(value, "signum", signal.SIGINT)
    with contextlib.suppress(Exception):
        sys.stdout.flush()
    name = signal.Signals(signum).name
    os.write(2, f"{_COMMAND}: stopped by {name}; no output was left half written\n".encode())
    os._exit(128 + signum)


def _stopped_unraisable(unraisable: Any) -> None:
    """``sys.unraisablehook`` of a command: a ``Stopped`` raised inside a gc callback or a
    ``__del__`` would be printed and lost (the command going on to its end): the signal is
    sent again a moment later (from a thread: sent here, it would land in this hook), to land
    in the command's own code."""
    if isinstance(unraisable.exc_value, Stopped):
        again = (os.getpid(), unraisable.exc_value.signum)
        threading.Timer(0.05, os.kill, again).start()
        return
    _previous_unraisablehook(unraisable)


_previous_unraisablehook = sys.unraisablehook

# ``python -m jaxnav.<command>`` imports this package first ("-m" is sys.argv[0] until the
# command's module runs): SIGINT or SIGTERM while JAX imports, before the command's ``main`` is
# defined, is one line and exit 130/143, not a traceback; later, the command unwinds first
_COMMAND = _command_of(getattr(sys, "orig_argv", []))
if sys.argv[:1] == ["-m"] and _COMMAND and threading.current_thread() is threading.main_thread():
    for _signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(_signum, _stopped_while_starting)
    sys.excepthook = _stopped_hook
    sys.unraisablehook = _stopped_unraisable


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
