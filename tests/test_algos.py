"""The algorithms behind one interface (``jaxnav.algos``): the training loop, config and
sharding name no algorithm, every registered one trains through the interface, and
checkpoints saved before the algorithms kept their own state still restore."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest
from conftest import TINY_TRAIN  # pytest puts tests/ on sys.path
from flax import struct

from jaxnav.algos import ALGOS
from jaxnav.algos.base import Algorithm, ProgramLayout
from jaxnav.checkpoints import Checkpoints
from jaxnav.sharding import is_key
from jaxnav.train import METRIC_NAMES, Trainer, program_layout

PACKAGE = Path(__file__).resolve().parents[1] / "jaxnav"
# the shared modules that must read an algorithm only through the registry
SHARED = (
    "train/__init__.py", "backend.py", "config.py", "sharding.py", "runner.py",
    "checkpoints.py",
)  # fmt: skip


def algorithm_branches(path: Path) -> list[str]:
    """Where the module at ``path`` names an algorithm: a string constant that is a
    registered name (the ``algo`` field's default aside) or a comparison of an ``algo`` with
    string constants (``algo == "x"``, ``algo in ("x", "y")``)."""
    tree = ast.parse(path.read_text())
    default = {  # the field's value, or the default its setting(...) gives first
        id(node.value.args[0] if isinstance(node.value, ast.Call) else node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", None) == "algo"
    }
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and node.value in ALGOS and id(node) not in default:
            found.append(f"{path.name}:{node.lineno} {node.value!r}")
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            names = [getattr(side, "attr", getattr(side, "id", None)) for side in sides]
            constants = [n for side in sides for n in ast.walk(side) if isinstance(n, ast.Constant)]
            if "algo" in names and any(isinstance(c.value, str) for c in constants):
                found.append(f"{path.name}:{node.lineno} compares algo with a name")
    return found


def test_the_shared_modules_name_no_algorithm(tmp_path):
    """Adding an algorithm is its module, presets and tests: the loop, config, sharding,
    runner and checkpoints branch on none (the registry is the one place that names them)."""
    assert {p: algorithm_branches(PACKAGE / p) for p in SHARED} == {p: [] for p in SHARED}
    # the check sees a branch where there is one
    assert algorithm_branches(PACKAGE / "presets.py")
    branch = tmp_path / "branch.py"
    branch.write_text('def f(c):\n    return 1 if c.algo in ("a", "b") else 2\n')
    assert algorithm_branches(branch) == ["branch.py:2 compares algo with a name"]


def backend_queries(path: Path) -> list[str]:
    """Where the module at ``path`` asks which backend it runs on: an import of a module
    named ``backend`` (``jaxnav.backend``) or of the training layer, or a use of
    ``jax.default_backend``, ``jax.devices`` or ``jax.local_devices``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import | ast.ImportFrom):
            modules = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom):
                modules = [f"{node.module or ''}.{a.name}" for a in node.names]
            for m in modules:
                if "backend" in m.split(".") or m.startswith("jaxnav.train"):
                    found.append(f"{path.name}:{node.lineno} imports {m}")
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id == "jax"
            and node.attr in ("default_backend", "devices", "local_devices")
        ):
            found.append(f"{path.name}:{node.lineno} jax.{node.attr}")
    return found


def test_the_algorithms_query_no_backend(tmp_path):
    """The algorithms read how their program is laid out for the backend from the loop
    (``Loop.layout``); the backend-specific choices are ``jaxnav.backend``'s, which the
    training layer resolves for them (``jaxnav.train.program_layout``)."""
    modules = sorted((PACKAGE / "algos").glob("*.py"))
    assert len(modules) >= 5
    assert {p.name: backend_queries(p) for p in modules} == {p.name: [] for p in modules}
    # the check sees a query where there is one
    assert backend_queries(PACKAGE / "backend.py")
    query = tmp_path / "query.py"
    query.write_text(
        "import jax\nfrom jaxnav import backend\nfrom jaxnav.train import program_layout\n"
        "x = jax.default_backend()\n"
    )
    assert backend_queries(query) == [
        "query.py:2 imports jaxnav.backend",
        "query.py:3 imports jaxnav.train.program_layout",
        "query.py:4 jax.default_backend",
    ]


def test_the_layout_on_a_cpu_is_the_cpu_choice():
    """On a CPU (where the tests run) every algorithm's program has loops of one gradient
    step a trip, rolled lambda-returns, a cond for the target update and no optimizer
    barrier; on a GPU each algorithm's own unroll and the other choices."""
    cpu = ProgramLayout(
        updates_unroll=1, returns_unrolled=False, target_update_select=False,
        optimizer_barrier=False,
    )  # fmt: skip
    assert jax.default_backend() == "cpu"
    for name, algorithm in sorted(ALGOS.items()):
        assert Trainer(dataclasses.replace(TINY_TRAIN, algo=name)).layout == cpu, name
        assert program_layout(algorithm.gpu_updates_unroll) == cpu, name
        assert program_layout(algorithm.gpu_updates_unroll, "cpu") == cpu, name
        assert program_layout(algorithm.gpu_updates_unroll, "gpu") == ProgramLayout(
            updates_unroll=algorithm.gpu_updates_unroll, returns_unrolled=True,
            target_update_select=True, optimizer_barrier=True,
        ), name  # fmt: skip
    assert {n: a.gpu_updates_unroll for n, a in ALGOS.items()} == {"dqn": 2, "pqn": 16, "ppo": 16}
    assert [cpu.unroll(n) for n in (1, 5)] == [1, 1]
    assert [ProgramLayout(updates_unroll=16).unroll(n) for n in (3, 16, 64)] == [3, 16, 16]


@pytest.mark.parametrize("name", sorted(ALGOS))
def test_every_registered_algorithm_trains_a_tiny_config_through_the_interface(name):
    algorithm = ALGOS[name]
    assert issubclass(algorithm, Algorithm)
    config = dataclasses.replace(TINY_TRAIN, algo=name)
    config.validate()
    assert config.updates_per_learning_iteration >= 1 and config.minibatch_size >= 1
    assert config.first_learning_iteration < config.iterations  # it learns within the run
    trainer = Trainer(config)
    assert isinstance(trainer.algorithm, algorithm)
    init = jax.jit(trainer.init)(jax.random.key(0))
    run = jax.jit(trainer.run, static_argnums=2)
    state, metrics = jax.device_get(run(init, 0, config.num_logs))
    assert set(metrics) == set(METRIC_NAMES)
    assert all(v.shape == (config.num_logs,) for v in metrics.values())
    assert all(np.isfinite(v).all() for v in metrics.values())
    assert metrics["loss"][-1] > 0 and int(state.diverged) == 0  # gradient steps were taken
    assert int(metrics["env_steps"][-1]) == config.iterations * config.steps_per_iteration
    before, after = jax.tree.leaves(jax.device_get(init.params)), jax.tree.leaves(state.params)
    assert all(not np.array_equal(a, b) for a, b in zip(before, after, strict=True))
    # the algorithm's own state keeps its structure and shapes through training
    shapes = lambda tree: jax.tree.map(lambda x: (x.shape, x.dtype), tree)  # noqa: E731
    assert shapes(state.algo_state) == shapes(jax.device_get(init.algo_state))


@struct.dataclass
class FormerTrainState:
    """``TrainState`` as checkpoints were saved before ``algo_state``: the DQN's target
    network and replay buffer as fields of their own, None for PQN."""

    params: Any
    target_params: Any
    opt_state: Any
    buffer: Any
    env_state: Any
    obs: Any
    episode_return: Any
    episode_length: Any
    key: Any
    hparams: Any
    diverged: Any
    diverged_at: Any


# the algorithms whose checkpoints were saved in that layout
FORMER_ALGOS = ("dqn", "pqn")


@pytest.mark.parametrize("name", FORMER_ALGOS)
def test_a_checkpoint_of_the_former_state_layout_restores_as_saved(name, tmp_path):
    trainer = Trainer(dataclasses.replace(TINY_TRAIN, algo=name))
    state = jax.device_get(jax.jit(jax.vmap(trainer.init))(jax.random.split(jax.random.key(3), 2)))
    algo_state = state.algo_state
    fields = {f: getattr(state, f) for f in state.__dataclass_fields__}
    del fields["algo_state"], fields["memory"], fields["curriculum"]  # both came later still
    former = FormerTrainState(
        **fields,
        target_params=getattr(algo_state, "target_params", None),
        buffer=getattr(algo_state, "buffer", None),
    )
    metrics = {"loss": np.arange(3, dtype=np.float32)[None]}
    saving = Checkpoints(tmp_path / "checkpoints", keep=1)
    saving.save(1, former, metrics, {"seconds": {}})
    saving.close()

    restoring = Checkpoints(tmp_path / "checkpoints", keep=1)
    like = jax.eval_shape(lambda: state)
    with pytest.raises(ValueError):  # not in today's layout
        restoring.restore(like, metrics)
    legacy = trainer.legacy_checkpoint_layouts(like)
    other = jax.tree.map(lambda x: jax.ShapeDtypeStruct((3, *x.shape[1:]), x.dtype), like)
    with pytest.raises(ValueError, match=r"was saved as \w+\[2.*this run expects \w+\[3"):
        restoring.restore(other, metrics, legacy=trainer.legacy_checkpoint_layouts(other))
    step, restored, restored_metrics, _ = restoring.restore(like, metrics, legacy=legacy)
    restoring.close()
    assert step == 1 and type(restored) is type(state)
    assert jax.tree.structure(restored) == jax.tree.structure(state)
    as_data = lambda x: jax.random.key_data(x) if is_key(x) else x  # noqa: E731
    for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(state), strict=True):
        np.testing.assert_array_equal(as_data(a), as_data(b))
    np.testing.assert_array_equal(restored_metrics["loss"], metrics["loss"])


@struct.dataclass
class TrainStateBeforeMemory:
    """``TrainState`` as checkpoints were saved before its ``memory`` field."""

    params: Any
    opt_state: Any
    algo_state: Any
    env_state: Any
    obs: Any
    episode_return: Any
    episode_length: Any
    key: Any
    hparams: Any
    diverged: Any
    diverged_at: Any


@struct.dataclass
class TrainStateBeforeCurriculum(TrainStateBeforeMemory):
    """``TrainState`` as checkpoints were saved before its ``curriculum`` field."""

    memory: Any = None


@pytest.mark.parametrize("former", [TrainStateBeforeMemory, TrainStateBeforeCurriculum])
@pytest.mark.parametrize("name", sorted(ALGOS))
def test_a_checkpoint_saved_before_memory_or_curriculum_restores_as_saved(name, former, tmp_path):
    trainer = Trainer(dataclasses.replace(TINY_TRAIN, algo=name))
    state = jax.device_get(jax.jit(jax.vmap(trainer.init))(jax.random.split(jax.random.key(3), 2)))
    fields = {f: getattr(state, f) for f in former.__dataclass_fields__}
    metrics = {"loss": np.arange(3, dtype=np.float32)[None]}
    saving = Checkpoints(tmp_path / "checkpoints", keep=1)
    saving.save(1, former(**fields), metrics, {"seconds": {}})
    saving.close()
    restoring = Checkpoints(tmp_path / "checkpoints", keep=1)
    like = jax.eval_shape(lambda: state)
    with pytest.raises(ValueError):  # not in today's layout
        restoring.restore(like, metrics)
    legacy = trainer.legacy_checkpoint_layouts(like)
    _, restored, _, _ = restoring.restore(like, metrics, legacy=legacy)
    restoring.close()
    assert type(restored) is type(state) and restored.memory is restored.curriculum is None
    assert jax.tree.structure(restored) == jax.tree.structure(state)
    as_data = lambda x: jax.random.key_data(x) if is_key(x) else x  # noqa: E731
    for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(state), strict=True):
        np.testing.assert_array_equal(as_data(a), as_data(b))


@pytest.mark.parametrize("name", sorted(set(ALGOS) - set(FORMER_ALGOS)))
def test_an_algorithm_added_since_has_no_former_layout_to_try(name, tmp_path):
    """Its state has fields that layout never held: a checkpoint is read in today's, or in
    the ones before ``TrainState.curriculum`` and ``TrainState.memory``, only."""
    trainer = Trainer(dataclasses.replace(TINY_TRAIN, algo=name))
    state = jax.device_get(jax.jit(jax.vmap(trainer.init))(jax.random.split(jax.random.key(3), 2)))
    like = jax.eval_shape(lambda: state)
    assert len(trainer.legacy_checkpoint_layouts(like)) == 2
    metrics = {"loss": np.arange(3, dtype=np.float32)[None]}
    saving = Checkpoints(tmp_path / "checkpoints", keep=1)
    saving.save(1, state, metrics, {"seconds": {}})
    saving.close()
    restoring = Checkpoints(tmp_path / "checkpoints", keep=1)
    _, restored, _, _ = restoring.restore(like, metrics)
    restoring.close()
    as_data = lambda x: jax.random.key_data(x) if is_key(x) else x  # noqa: E731
    assert jax.tree.structure(restored) == jax.tree.structure(state)
    for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(state), strict=True):
        np.testing.assert_array_equal(as_data(a), as_data(b))
