"""``python -m jaxnav.pretrained``: list the shipped policies, or add one.

    python -m jaxnav.pretrained
    python -m jaxnav.pretrained add NAME policy.npz --command "python -m jaxnav.train ..." \\
        --command "python -m jaxnav.export RUN --out policy.npz" [--episodes 1000] [--seed 20000]

``add`` checks the npz is a jaxnav policy, measures its greedy success on fresh episodes of its
env, copies it into the package as NAME.npz and writes its manifest entry; a name already
shipped is replaced only with ``--force``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from jaxnav.cli import Parser, UsageError, check_seed, fail, write_failed
from jaxnav.deploy.policy import Policy
from jaxnav.pretrained import HERE, manifest
from jaxnav.safe_io import WriteFault


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
    add.add_argument("--force", action="store_true", help="replace a policy of that name")
    try:
        args = p.parse_args(argv)
        if args.verb == "add":
            if not args.name.replace("-", "").replace("_", "").isalnum():
                raise UsageError(f"name {args.name!r}: letters, digits, - and _ only")
            if not args.file.is_file():
                why = "not a regular file" if args.file.exists() else "no such file"
                raise ValueError(f"{args.file}: {why}")
            if not args.command:
                raise UsageError("--command: give the commands that made the policy")
            if not 1 <= args.episodes <= 10**7:
                raise UsageError(f"--episodes {args.episodes}: must be in [1, 10000000]")
            check_seed(args.seed)
            shipped = args.name in manifest() or (HERE / f"{args.name}.npz").exists()
            if shipped and not args.force:
                raise UsageError(
                    f"name {args.name!r}: a policy of that name is shipped; pass --force to "
                    "replace it"
                )
            Policy.load(args.file)  # a damaged or foreign file: one line, before any copy
    except (UsageError, ValueError, OSError) as e:
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

    try:
        entry = add_entry(args.name, args.file, args.command, args.episodes, args.seed, args.note)
    except WriteFault as e:  # the package directory is full or read-only
        return write_failed("jaxnav.pretrained", e)
    except ValueError as e:  # the policy's env cannot be built here
        return fail("jaxnav.pretrained", str(e))
    m = entry["measured"]
    print(f"added {args.name}: success {m['success_rate']:.3f} on {m['episodes']} episodes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
