"""The package's import graph, drawn from the source with ``ast`` (every import statement,
including those inside functions and ``TYPE_CHECKING`` blocks): no circles, no arrow that runs
back up the layers, and no module importing another module's private name."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxnav"

# Bottom layer first. A module imports only modules of its own group or of a lower layer, so
# groups side by side in one layer never import each other: the envs never import an agent,
# the agents never import an env, and nothing below the commands imports a command.
# A module belongs to the group with the longest name that is its name or a parent package
# of it (the root ``jaxnav`` holds only ``jaxnav/__init__.py``).
LAYERS: list[list[str]] = [
    # deploy: numpy only, no JAX
    [
        "jaxnav.spaces",
        "jaxnav.sharding",
        "jaxnav.safe_io",
        "jaxnav.deploy",
        "jaxnav.loggers",
        "jaxnav.host",
        "jaxnav.version",
        "jaxnav.backend",  # every backend-dependent choice; imports jax only
    ],
    ["jaxnav.pretrained"],
    ["jaxnav.environment", "jaxnav.checkpoints"],
    ["jaxnav.envs", "jaxnav.agents", "jaxnav.wrappers"],
    ["jaxnav.algos"],  # each algorithm behind one interface; config validates with them
    ["jaxnav.registration"],
    ["jaxnav", "jaxnav.presets"],
    ["jaxnav.config"],
    ["jaxnav.train"],  # the Trainer
    ["jaxnav.evaluate", "jaxnav.programs"],
    ["jaxnav.run_dir"],
    ["jaxnav.runner"],
    ["jaxnav.cli"],  # the helpers every command line shares
    ["jaxnav.export"],
    ["jaxnav.render"],
    ["jaxnav.plots"],
    ["jaxnav.experiments"],
    ["jaxnav.pretrained.check"],  # measures a shipped policy in the simulator
    ["jaxnav.train.__main__", "jaxnav.evaluate.__main__", "jaxnav.pretrained.__main__"],
]
LAYER = {group: rank for rank, groups in enumerate(LAYERS) for group in groups}


def module_name(package: Path, path: Path) -> str:
    parts = ["jaxnav", *path.relative_to(package).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def group_of(module: str) -> str | None:
    if module == "jaxnav":
        return "jaxnav"
    parts = module.split(".")
    for n in range(len(parts), 1, -1):
        if ".".join(parts[:n]) in LAYER:
            return ".".join(parts[:n])
    return None


def read_graph(package: Path) -> tuple[dict[str, set[str]], list[str]]:
    """``(module -> the package's modules it imports, private names taken from another
    module)`` of the package in directory ``package``."""
    files = {module_name(package, p): p for p in sorted(package.rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    private: list[str] = []
    for module, path in files.items():
        tree = ast.parse(path.read_text(), str(path))
        here = module if path.name == "__init__.py" else module.rpartition(".")[0]
        targets: set[str] = set()
        aliases: dict[str, str] = {}  # local name -> the module bound to it
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    targets.add(a.name)
                    if a.asname:
                        aliases[a.asname] = a.name
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = here.split(".")[: len(here.split(".")) - node.level + 1]
                    base = ".".join([*anchor, *([base] if base else [])])
                for a in node.names:
                    if f"{base}.{a.name}" in files:  # ``from jaxnav import run_dir``
                        targets.add(f"{base}.{a.name}")
                        aliases[a.asname or a.name] = f"{base}.{a.name}"
                        continue
                    targets.add(base)
                    if _private(a.name) and base in files and base != module:
                        private.append(f"{module}: from {base} import {a.name}")
        for node in ast.walk(tree):  # ``module._name`` through a name bound to a module
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and aliases.get(node.value.id, module) != module
                and _private(node.attr)
            ):
                private.append(f"{module}: {aliases[node.value.id]}.{node.attr}")
        graph[module] = {t for t in targets if t in files and t != module}
    return graph, private


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def upward_arrows(graph: dict[str, set[str]]) -> list[str]:
    """Arrows to another group that is not in a lower layer."""
    return [
        f"{m} -> {t}"
        for m, targets in sorted(graph.items())
        for t in sorted(targets)
        if group_of(t) != group_of(m) and LAYER[group_of(t)] >= LAYER[group_of(m)]
    ]


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Depth-first search: an arrow back to a module on the current path closes a circle."""
    state: dict[str, int] = {}  # 1 on the path, 2 done
    found: list[list[str]] = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                found.append([*path[path.index(t) :], t])
            elif t not in state:
                visit(t, [*path, t])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    return found


GRAPH, PRIVATE = read_graph(PACKAGE)


def test_graph_is_read_from_the_package():
    """The graph has arrows known to be there, ``from package import module`` ones too."""
    assert len(GRAPH) > 20
    assert "jaxnav.train" in GRAPH["jaxnav.runner"]
    assert "jaxnav.runner" in GRAPH["jaxnav.train.__main__"]
    assert "jaxnav.environment" in GRAPH["jaxnav.envs.grid_maze"]
    assert "jaxnav.envs.robot.env" in GRAPH["jaxnav.registration"]


def test_every_module_has_a_layer():
    assert [m for m in GRAPH if group_of(m) is None] == []


def test_no_arrow_runs_up_or_sideways():
    assert upward_arrows(GRAPH) == []


def test_no_circles():
    assert circles(GRAPH) == []


def test_no_module_imports_a_private_name_of_another():
    assert PRIVATE == []


def test_checks_find_what_they_forbid(tmp_path):
    """A private import, a private attribute, an upward arrow and a circle, on purpose."""
    fake = tmp_path / "jaxnav"
    (fake / "envs").mkdir(parents=True)
    (fake / "__init__.py").write_text("")
    (fake / "envs" / "__init__.py").write_text("")
    (fake / "spaces.py").write_text("from jaxnav.envs.a import _hidden\n")
    (fake / "envs" / "a.py").write_text("from . import b\nimport jaxnav.spaces\n")
    (fake / "envs" / "b.py").write_text("from jaxnav.envs import a\n\n_x = a._y\n")
    graph, private = read_graph(fake)
    assert private == [
        "jaxnav.envs.b: jaxnav.envs.a._y",
        "jaxnav.spaces: from jaxnav.envs.a import _hidden",
    ]
    assert upward_arrows(graph) == ["jaxnav.spaces -> jaxnav.envs.a"]
    a, b, spaces = "jaxnav.envs.a", "jaxnav.envs.b", "jaxnav.spaces"
    assert circles(graph) == [[a, b, a], [a, spaces, a]]
