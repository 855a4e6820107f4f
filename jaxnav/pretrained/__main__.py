"""``python -m jaxnav.pretrained``: list the shipped policies, or add one.

    python -m jaxnav.pretrained
    python -m jaxnav.pretrained add NAME policy.npz --command "python -m jaxnav.train ..." \\
        --command "python -m jaxnav.export RUN --out policy.npz" [--episodes 1000] [--seed 20000]

``add`` copies the npz into the package as NAME.npz, measures its greedy success on fresh
episodes of its env and writes its manifest entry.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from jaxnav.cli import Parser, UsageError, fail
from jaxnav.pretrained import HERE, manifest


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="python -m jaxnav.pretrained", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="verb")
    add = sub.add_parser("add", help="copy an exported npz in, measure it, write its entry")
    add.add_argument("name")
    add.add_argument("file", type=Path)
    add.add_argument("--command", action="append", default=[], help="a command that made it")
    add.add_argument("--episodes", type=int, default=1000)
    add.add_argument("--seed", type=int, default=20_000, help="seed of the test episodes")
    add.add_argument("--note", default="")
    try:
        args = p.parse_args(argv)
        if args.verb == "add":
            if not args.name.replace("-", "").replace("_", "").isalnum():
                raise UsageError(f"name {args.name!r}: letters, digits, - and _ only")
            if not args.file.is_file():
                raise ValueError(f"{args.file}: no such file")
            if not args.command:
                raise UsageError("--command: give the commands that made the policy")
    except (UsageError, ValueError) as e:
        return fail("jaxnav.pretrained", str(e))
    if args.verb != "add":
        for name, e in sorted(manifest().items()):
            m = e["measured"]
            print(
                f"{name}: {e['env_id']} {e['env_kwargs']}, success {m['success_rate']:.3f} on "
                f"{m['episodes']} episodes (seed {m['seed']}), {e['file']}"
            )
        return 0
    from jaxnav.pretrained.check import add_entry

    target = HERE / f"{args.name}.npz"
    if args.file.resolve() != target:
        shutil.copyfile(args.file, target)
    entry = add_entry(args.name, target, args.command, args.episodes, args.seed, args.note)
    m = entry["measured"]
    print(f"added {args.name}: success {m['success_rate']:.3f} on {m['episodes']} episodes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
