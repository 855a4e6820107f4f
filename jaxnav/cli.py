"""What every command line shares: one-line errors and the env override flags.

Bad input of any kind is one line on stderr naming the value, exit code 2, nothing written.
A write the machine refuses (no space left, a read-only file system, permission denied, an I/O
error) is one line naming the path and the remedy, exit code 4, nothing partial left.
Each command parses its own flags in its own module and calls the library:
``python -m jaxnav.train`` (``jaxnav/train/__main__.py``, over ``jaxnav.runner``),
``python -m jaxnav.evaluate`` (``jaxnav/evaluate/__main__.py``), ``python -m jaxnav.render``
and ``python -m jaxnav.experiments``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from jaxnav.safe_io import EXIT_WRITE_FAULT, WriteFault


class UsageError(Exception):
    """Bad command-line input: reported as one line, exit code 2."""


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults in ``--help``, except where there is none (``None``) or the help text already
    says what the default is."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if action.default is None or "default" in text or action.default is argparse.SUPPRESS:
            return text
        return super()._get_help_string(action) or text


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are ``UsageError`` (one line, no usage dump). Flags
    are never abbreviated (``--num-seed`` is not ``--num-seeds``), and an unknown flag that
    names an env config field is answered with the ``--env-arg`` that sets it."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> None:  # one line, no usage dump
        if message.startswith("unrecognized arguments:") and any(
            a.dest == "env_arg" for a in self._actions
        ):
            message += env_arg_hint(message.split(":", 1)[1].split())
        raise UsageError(one_line(message))


def env_config_fields() -> set[str]:
    """Field names of every registered env's config (what ``--env-arg`` can set)."""
    import dataclasses

    from jaxnav.registration import env_config, registered_envs

    fields: set[str] = set()
    for env_id in registered_envs():
        try:
            fields |= {f.name for f in dataclasses.fields(env_config(env_id))}
        except ValueError:  # RobotMaze-v0 needs a maze file; its fields are RobotSimple-v0's
            continue
    return fields


def env_arg_hint(tokens: Sequence[str]) -> str:
    """``; did you mean --env-arg backend=...`` for the first unknown flag in ``tokens`` that
    names an env config field (``--backend`` or ``--backend=kinematic``), else ``""``."""
    fields = env_config_fields()
    for i, token in enumerate(tokens):
        if not token.startswith("--"):
            continue
        name, eq, value = token[2:].partition("=")
        key = name.replace("-", "_")
        if key in fields:
            if not eq:
                nxt = tokens[i + 1] if i + 1 < len(tokens) else ""
                value = "..." if not nxt or nxt.startswith("-") else nxt
            return f"; did you mean --env-arg {key}={value}"
    return ""


def one_line(message: str) -> str:
    """An error quotes the user's text (a value, a path) verbatim; a line break in it must
    not split the error over lines."""
    return message.replace("\r", "\\r").replace("\n", "\\n")


def fail(prog: str, message: str) -> int:
    """Print ``prog: error: message`` as one line on stderr; returns the exit code, 2."""
    print(f"{prog}: error: {one_line(message)}", file=sys.stderr)
    return 2


def write_failed(prog: str, error: WriteFault) -> int:
    """Print a write the machine refused (a full disk, a read-only file system) as one line;
    returns its exit code, ``EXIT_WRITE_FAULT`` (4)."""
    print(f"{prog}: error: {one_line(str(error))}", file=sys.stderr)
    return EXIT_WRITE_FAULT


MAX_SEED = 2**31 - 1  # as training's seed: jax.random.key takes a signed 32-bit one


def check_seed(seed: int, flag: str = "--seed") -> None:
    """``UsageError`` (one line) unless ``seed`` is in [0, ``MAX_SEED``]."""
    if not 0 <= seed <= MAX_SEED:
        raise UsageError(f"{flag} {seed}: must be in [0, {MAX_SEED}]")


def parse_bool(text: str) -> bool:
    """An argparse ``type`` for true/false flags (also 1/0, yes/no, on/off)."""
    t = text.lower()
    if t in ("true", "1", "yes", "on"):
        return True
    if t in ("false", "0", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"invalid boolean {text!r} (use true or false)")


def parse_env_arg(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` to ``(key, value)``, the value as JSON where it parses, else a string."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"invalid override {text!r} (use KEY=VALUE)")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value  # a bare string, e.g. obs_mode=paper
    except RecursionError:  # "[[[[..." tens of thousands deep
        raise argparse.ArgumentTypeError(
            f"invalid override {one_line(text[:40])!r}...: nested too deeply"
        ) from None


def parse_path(text: str) -> Path:
    """An argparse ``type`` for a file path: ``Path('')`` is the current directory, so an
    empty path (an unset shell variable) is refused rather than read as '.'."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"empty path {text!r} (give a file)")
    return Path(text)


def add_env_args(p: argparse.ArgumentParser) -> None:
    """``--env-arg KEY=VALUE`` (repeatable) and ``--maze-file PATH``."""
    p.add_argument(
        "--env-arg",
        type=parse_env_arg,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="environment override, repeatable, each KEY once (e.g. size=11, obs_mode=paper)",
    )
    p.add_argument(
        "--maze-file",
        type=parse_path,
        metavar="PATH",
        help="your own maze as a text file (README: Robot mazes; a UTF-8 BOM is skipped); the "
        "env id defaults to RobotMaze-v0",
    )


def env_from_args(args: argparse.Namespace, env: str | None) -> tuple[str | None, dict[str, Any]]:
    """``(env id, env overrides)`` from ``--env-arg`` and ``--maze-file`` (which implies
    RobotMaze-v0 unless an id is given); ``UsageError`` for an empty ``--env`` (it would be
    the default env) or a key given twice (the last would silently win)."""
    if env is not None and not env.strip():
        raise UsageError(f"--env {env!r}: empty; give an env id or leave --env out")
    env_kwargs: dict[str, Any] = {}
    for key, value in args.env_arg or []:
        if key in env_kwargs:
            raise UsageError(
                f"--env-arg {key} given twice ({env_kwargs[key]!r}, then {value!r}); give it once"
            )
        env_kwargs[key] = value
    if getattr(args, "maze_file", None) is not None:
        if "maze_file" in env_kwargs:
            raise UsageError("--maze-file and --env-arg maze_file=... both given; give one")
        env_kwargs["maze_file"] = str(args.maze_file)
        env = env or "RobotMaze-v0"
    return env, env_kwargs


def add_policy_source(p: argparse.ArgumentParser, pretrained_help: str) -> None:
    """The policy to run: a trained run directory, or ``--pretrained NAME`` (one of them,
    ``check_policy_source``)."""
    p.add_argument("run", type=Path, nargs="?", help="run directory written by jaxnav.train")
    p.add_argument("--pretrained", metavar="NAME", help=pretrained_help)


def check_policy_source(args: argparse.Namespace) -> None:
    """``UsageError`` unless exactly one of a run directory and ``--pretrained`` (a name) was
    given."""
    if (args.run is None) == (args.pretrained is None):
        raise UsageError("give a run directory or --pretrained NAME, one of them")
    if args.pretrained is not None and not args.pretrained.strip():
        raise UsageError(f"--pretrained {args.pretrained!r}: empty; give a shipped policy's name")
