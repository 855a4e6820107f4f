"""Exported policies (``jaxnav.export``): the ONNX graph in onnxruntime and the npz in plain
numpy compute the JAX network's Q-values and greedy actions on 10,000 observations; the
metadata describes the observation; the CLI refuses bad input in one line and writes nothing
half."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import SMALL_GRID_FLAGS  # pytest puts tests/ on sys.path

from jaxnav import export
from jaxnav.config import TrainConfig
from jaxnav.deploy.policy import Policy, describe
from jaxnav.train import Trainer
from jaxnav.train.__main__ import main as train_main

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

NUM_OBS = 10_000
CASES = {
    # the grid's compact index observation: the network one-hot encodes 4 of its 10 values
    "grid-index": TrainConfig(env="GridMaze-v0", env_kwargs={"size": 7}, hidden_sizes=(64, 32)),
    "grid-sensor": TrainConfig(
        env="GridMaze-Random-v0",
        env_kwargs={"size": 7, "num_layouts": 8, "goals_per_layout": 4},
        hidden_sizes=(32,),
        dueling=False,
    ),
    # the paper's robot layout: absolute coordinates in the frame
    "robot-absolute": TrainConfig(
        env="RobotSimple-v0",
        env_kwargs={"backend": "kinematic"},
        hidden_sizes=(64, 32),
        layer_norm=True,
        dueling=False,
    ),
    # the generalist's: no absolute coordinates, 32 beams all around, a waypoint
    "robot-generalist": TrainConfig(
        env="RobotNav-v0", env_kwargs={"num_layouts": 8}, hidden_sizes=(64, 32), layer_norm=True
    ),
}


def observations(trainer: Trainer, num: int = NUM_OBS) -> np.ndarray:
    """``num`` observations of the env: fresh episodes and 15 random steps of each."""
    env, params = trainer.env, trainer.env_params
    steps = 16

    def run(key):
        k_reset, k_run = jax.random.split(key)
        keys = jax.random.split(k_reset, num // steps)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

        def body(carry, key):
            obs, state = carry
            k_act, k_step = jax.random.split(key)
            action = jax.random.randint(k_act, obs.shape[:1], 0, env.num_actions)
            keys = jax.random.split(k_step, obs.shape[0])
            obs2, state, *_ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                keys, state, action, params
            )
            return (obs2, state), obs

        return jax.lax.scan(body, (obs, state), jax.random.split(k_run, steps))[1]

    return np.asarray(jax.jit(run)(jax.random.key(11))).reshape(num, -1)


def random_params(trainer: Trainer, key: jax.Array):
    """The network's initial parameters, every one moved by noise (biases and LayerNorm
    scales included, which start at 0 and 1), so a misplaced array would show."""
    params = trainer.network.init(key, jnp.zeros((1, trainer.obs_size)))
    leaves, tree = jax.tree.flatten(params)
    keys = jax.random.split(key, len(leaves))
    noisy = [x + 0.2 * jax.random.normal(k, x.shape) for x, k in zip(leaves, keys, strict=True)]
    return jax.tree.unflatten(tree, noisy)


@pytest.fixture(scope="module", params=list(CASES))
def exported(request, tmp_path_factory):
    """``(trainer, params, obs, JAX Q-values, npz path, onnx path)`` of a random network."""
    trainer = Trainer(CASES[request.param])
    params = random_params(trainer, jax.random.key(3))
    obs = observations(trainer)
    q = np.asarray(jax.jit(trainer.network.apply)(params, jnp.asarray(obs)))
    arrays = export.policy_arrays(trainer.network, params)
    metadata = export.policy_metadata(trainer, {"test": request.param})
    out = tmp_path_factory.mktemp(request.param)
    npz = export.write_policy(arrays, metadata, out / "policy.npz", "npz")
    onnx_path = export.write_policy(arrays, metadata, out / "policy.onnx", "onnx")
    return trainer, params, obs, q, npz, onnx_path


def assert_same_policy(q_jax: np.ndarray, q: np.ndarray, action: np.ndarray) -> None:
    """Q-values equal within float32 rounding, and the same greedy actions wherever the
    JAX network's two best Q-values are not themselves within rounding of each other."""
    scale = float(np.abs(q_jax).max())
    np.testing.assert_allclose(q, q_jax, rtol=1e-5, atol=2e-6 * scale)
    top2 = np.sort(q_jax, axis=-1)[:, -2:]
    decided = top2[:, 1] - top2[:, 0] > 1e-5 * scale
    assert decided.mean() > 0.999  # near-ties are rare: the comparison covers the policy
    np.testing.assert_array_equal(action[decided], q_jax.argmax(-1)[decided])


def test_npz_in_numpy_acts_as_the_jax_policy(exported):
    _, _, obs, q_jax, npz, _ = exported
    policy = Policy.load(npz)
    q = policy.q_values(obs)
    assert q.dtype == np.float32 and q.shape == q_jax.shape
    assert_same_policy(q_jax, q, policy.act(obs))
    assert policy.act(obs[0]) == int(policy.act(obs[:1])[0])  # one observation: an int


def test_onnx_in_onnxruntime_acts_as_the_jax_policy(exported):
    _, _, obs, q_jax, _, onnx_path = exported
    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    q, action = session.run(["q_values", "action"], {"obs": obs.astype(np.float32)})
    assert_same_policy(q_jax, q, action)
    np.testing.assert_array_equal(action, q.argmax(-1))  # ArgMax picks the first largest


def test_metadata_is_the_same_in_both_files_and_describes_every_input(exported):
    trainer, _, obs, _, npz, onnx_path = exported
    meta = Policy.load(npz).metadata
    assert export.onnx_metadata(onnx_path) == meta
    layout = meta["observation"]
    assert layout["size"] == trainer.obs_size == obs.shape[1] == meta["network"]["obs_size"]
    assert [e["index"] for e in layout["entries"]] == list(range(layout["size"]))
    assert len(meta["actions"]) == trainer.env.num_actions
    assert meta["env_id"] == trainer.config.env and meta["env_kwargs"] == trainer.config.env_kwargs
    model = onnx.load(str(onnx_path))
    ops = {n.op_type for n in model.graph.node}
    assert {"MatMul", "Add", "Relu", "ArgMax"} <= ops
    assert ("LayerNormalization" in ops) == trainer.config.layer_norm
    assert ("ReduceMean" in ops) == trainer.config.dueling
    if layout.get("frames", 1) > 1:  # every frame has the same entries, oldest first
        frame = layout["frame_size"]
        names = [e["name"] for e in layout["entries"]]
        assert names == names[:frame] * layout["frames"]


def test_no_action_from_a_non_finite_observation(exported):
    """A NaN gave NaN Q-values and action 0 (drive forward): refused, naming where it is."""
    *_, obs, _, npz, _ = exported
    policy = Policy.load(npz)
    for value in (np.nan, np.inf, -np.inf):
        bad = obs[:3].astype(np.float64)  # the grid's index observations are integers
        bad[2, 1] = value
        with pytest.raises(ValueError, match=rf"observation\[2, 1\]={value}: not finite"):
            policy.act(bad)
        with pytest.raises(ValueError, match=rf"observation\[1\]={value}: not finite"):
            policy.q_values(bad[2])


def test_a_damaged_policy_file_is_named_in_one_line(exported, tmp_path, capsys):
    from jaxnav.deploy.policy import main as describe_main

    npz = exported[4]
    data = npz.read_bytes()
    cases = {
        "truncated": (data[: len(data) // 2], "truncated or damaged policy file"),
        "garbage": (bytes(range(256)) * 4, "not a jaxnav policy file (not an npz archive)"),
        "empty": (b"", "not a jaxnav policy file"),
        "no metadata": (None, "not a jaxnav policy file (no metadata)"),
    }
    for name, (content, named) in cases.items():
        path = tmp_path / f"{name}.npz"
        if content is None:
            np.savez(path, dense0_kernel=np.zeros((2, 2), np.float32))
        else:
            path.write_bytes(content)
        with pytest.raises(ValueError, match=re.escape(f"{path}: {named}")):
            Policy.load(path)
        assert describe_main([str(path)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(path) in err and named in err, (name, err)


@pytest.fixture(scope="module")
def small_export(tmp_path_factory):
    """``(arrays, metadata, npz path, onnx path)`` of a small random grid network."""
    trainer = Trainer(CASES["grid-sensor"])
    arrays = export.policy_arrays(trainer.network, random_params(trainer, jax.random.key(5)))
    metadata = export.policy_metadata(trainer)
    out = tmp_path_factory.mktemp("small")
    npz = export.write_policy(arrays, metadata, out / "policy.npz", "npz")
    return arrays, metadata, npz, export.write_policy(arrays, metadata, out / "policy.onnx", "onnx")


def test_a_changed_weight_in_an_exported_npz_is_refused_naming_the_file_and_array(
    small_export, tmp_path, capsys
):
    """A valid archive whose weights differ from the checksums written with them (a flipped
    bit that the zip's own CRC cannot see, rewritten whole) is refused, never acted on."""
    from jaxnav.deploy.policy import main as describe_main

    _, _, npz, _ = small_export
    with np.load(npz) as f:
        stored = dict(f)
    assert set(json.loads(str(stored["checksum"]))) == set(stored) - {"checksum"}
    kernel = stored["dense0_kernel"].copy()
    kernel.view(np.uint8)[7] ^= 0x10  # one bit of one weight
    for name, changed in {
        "flipped": {**stored, "dense0_kernel": kernel},
        "missing": {k: v for k, v in stored.items() if k != "head_bias"},
        "added": {**stored, "extra": np.zeros(2, np.float32)},
        "checksums": {**stored, "checksum": np.array("not json")},
    }.items():
        path = tmp_path / f"{name}.npz"
        np.savez_compressed(path, **changed)
        with pytest.raises(ValueError, match=re.escape(f"{path}: damaged policy file")):
            Policy.load(path)
        assert describe_main([str(path)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(path) in err, (name, err)
    err_of_flip = str(pytest.raises(ValueError, Policy.load, tmp_path / "flipped.npz").value)
    assert "array 'dense0_kernel' differs from its checksum" in err_of_flip
    # a flipped byte anywhere in the file itself: one line naming it, whatever it hit
    data = bytearray(npz.read_bytes())
    for i in range(0, len(data), max(1, len(data) // 40)):
        path = tmp_path / f"byte{i}.npz"
        path.write_bytes(bytes(data[:i]) + bytes([data[i] ^ 0x01]) + bytes(data[i + 1 :]))
        try:
            Policy.load(path)
        except ValueError as e:
            assert str(e).startswith(f"{path}: ") and "\n" not in str(e)


def test_policies_exported_before_checksums_still_load(small_export, tmp_path):
    """Files written before the checksum existed: the npz without its ``checksum`` array and
    the ONNX model without its ``checksum`` property load as before, unchecked."""
    arrays, metadata, npz, onnx_path = small_export
    old = tmp_path / "old.npz"
    np.savez_compressed(old, **arrays, metadata=np.array(json.dumps(metadata)))
    assert Policy.load(old).metadata == Policy.load(npz).metadata
    model = onnx.load(str(onnx_path))
    kept = [p for p in model.metadata_props if p.key != "checksum"]
    assert len(kept) == len(model.metadata_props) - 1
    del model.metadata_props[:]
    model.metadata_props.extend(kept)
    old_onnx = tmp_path / "old.onnx"
    onnx.save(model, str(old_onnx))
    assert export.onnx_metadata(old_onnx) == metadata


def test_a_changed_weight_in_an_exported_onnx_is_refused_naming_the_file(small_export, tmp_path):
    from onnx import numpy_helper

    *_, onnx_path = small_export
    model = onnx.load(str(onnx_path))
    first = model.graph.initializer[0]
    value = numpy_helper.to_array(first).copy()
    value.reshape(-1)[0] += 1
    first.CopyFrom(numpy_helper.from_array(value, first.name))
    path = tmp_path / "changed.onnx"
    onnx.save(model, str(path))
    with pytest.raises(ValueError, match=re.escape(f"{path}: damaged policy file (array ")):
        export.onnx_metadata(path)
    truncated = tmp_path / "truncated.onnx"
    truncated.write_bytes(onnx_path.read_bytes()[:100])
    with pytest.raises(ValueError, match=re.escape(f"{truncated}: ")):
        export.load_onnx(truncated)


def test_grid_index_layout_reads_the_state():
    """The grid's layout names say which value is what: rebuilt from the state by name, the
    observation is the env's."""
    trainer = Trainer(CASES["grid-index"])
    env, params = trainer.env, trainer.env_params
    meta = export.policy_metadata(trainer)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(
        jax.random.split(jax.random.key(0), 64), params
    )
    obs = np.asarray(jax.vmap(env.get_obs, in_axes=(0, None))(state, params))
    pos, goal = np.asarray(state.pos), np.asarray(state.goal)
    obstacles = np.pad(np.asarray(params.bank.obstacles[0]), 1, constant_values=True)
    moves = {"up": (-1, 0), "down": (1, 0), "left": (0, -1), "right": (0, 1)}
    for e in meta["observation"]["entries"]:
        name = e["name"]
        if name.startswith("blocked_"):
            dr, dc = moves[name.removeprefix("blocked_")]
            want = obstacles[pos[:, 0] + 1 + dr, pos[:, 1] + 1 + dc]
        else:
            want = {
                "robot_row": pos[:, 0],
                "robot_col": pos[:, 1],
                "goal_row": goal[:, 0],
                "goal_col": goal[:, 1],
                "goal_drow": goal[:, 0] - pos[:, 0],
                "goal_dcol": goal[:, 1] - pos[:, 1],
            }[name]
        np.testing.assert_array_equal(obs[:, e["index"]], want * e["scale"], err_msg=name)
    assert meta["network"]["onehot_sizes"] == [7, 7, 7, 7, 0, 0, 0, 0, 0, 0]


def test_flax_params_invert_policy_arrays(exported):
    trainer, params, obs, q_jax, npz, _ = exported
    policy = Policy.load(npz)
    back = export.flax_params(policy.arrays, policy.network)
    apply = jax.jit(trainer.network.apply)
    jax.tree.map(np.testing.assert_array_equal, back, params)
    np.testing.assert_array_equal(apply(back, obs[:100]), apply(params, obs[:100]))


def test_deploy_modules_run_without_jax(exported):
    """``jaxnav.deploy`` imports neither JAX nor flax: a fresh interpreter loads the npz and
    acts with numpy alone."""
    _, _, obs, q_jax, npz, _ = exported
    np.save(npz.with_name("obs.npy"), obs[:50])
    code = (
        "import sys, numpy as np\n"
        "from jaxnav.deploy.policy import Policy\n"
        "import jaxnav.deploy.sensors\n"
        "import jaxnav.deploy.navigator\n"
        "import jaxnav.deploy.planner\n"
        f"p = Policy.load({str(npz)!r})\n"
        f"print(' '.join(map(str, p.act(np.load({str(npz.with_name('obs.npy'))!r})))))\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'flax'))\n"
        "assert not bad, bad\n"
    )
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": f"{root}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    assert [int(a) for a in out.stdout.split()] == list(q_jax[:50].argmax(-1))


# ------------------------------------------------------------------ a trained run, the CLI
TINY = [*SMALL_GRID_FLAGS, "--quiet"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    """A run trained on this CPU by the training CLI (two seeds, 4,000 steps)."""
    out = tmp_path_factory.mktemp("runs") / "tiny"
    assert train_main([*TINY, "--out", str(out)]) == 0
    return out


def test_cli_exports_a_trained_run_in_both_formats(tiny_run, capsys):
    assert export.main([str(tiny_run), "--format", "onnx"]) == 0
    assert export.main([str(tiny_run), "--run-seed", "1", "--out", str(tiny_run / "s1.npz")]) == 0
    assert "wrote" in capsys.readouterr().out
    trainer, params0, seed0 = export.load_run(tiny_run)
    _, params1, seed1 = export.load_run(tiny_run, run_seed=1)
    assert (seed0, seed1) == (0, 1)
    obs = observations(trainer)
    session = ort.InferenceSession(str(tiny_run / "policy.onnx"))
    q, action = session.run(None, {"obs": obs.astype(np.float32)})
    q_jax = np.asarray(trainer.network.apply(params0, jnp.asarray(obs)))
    assert_same_policy(q_jax, q, action)
    policy = Policy.load(tiny_run / "s1.npz")
    q_jax1 = np.asarray(trainer.network.apply(params1, jnp.asarray(obs)))
    assert_same_policy(q_jax1, policy.q_values(obs), policy.act(obs))
    meta = export.onnx_metadata(tiny_run / "policy.onnx")
    summary = json.loads((tiny_run / "summary.json").read_text())
    assert meta["source"]["run_seed"] == 0
    assert (
        meta["source"]["run_evaluation"]["success_rate"]
        == (summary["trained_per_seed"][0]["success_rate"])
    )
    assert policy.metadata["source"]["run_seed"] == 1


@pytest.mark.parametrize(
    "args, message",
    [
        (["{run}", "--format", "tflite"], "argument --format: invalid choice: 'tflite'"),
        (["{run}", "--format", "onnx", "--out", "{run}/p.npz"], "must end in .onnx"),
        (["{run}", "--out", "{run}/missing/p.npz"], "directory {run}/missing does not exist"),
        (["{run}", "--run-seed", "7"], r"--run-seed 7: the run has seeds \[0, 1\]"),
        (["{run}/nope"], "{run}/nope: not a run directory"),
        (["{run}/params"], "not a run directory"),
    ],
)
def test_cli_refuses_bad_input_in_one_line_and_writes_nothing(tiny_run, capsys, args, message):
    before = sorted(p.name for p in tiny_run.iterdir())
    argv = [a.format(run=tiny_run) for a in args]
    assert export.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("jaxnav.export: error: ")
    assert re.search(message.format(run=re.escape(str(tiny_run))), err), err
    assert sorted(p.name for p in tiny_run.iterdir()) == before


def test_an_unfinished_run_is_refused(tiny_run, tmp_path, capsys):
    run = tmp_path / "unfinished"
    run.mkdir()
    (run / "config.json").write_text((tiny_run / "config.json").read_text())
    assert export.main([str(run)]) == 2
    assert "no trained parameters" in capsys.readouterr().err
    assert sorted(p.name for p in run.iterdir()) == ["config.json"]


def test_a_failed_write_leaves_the_previous_file(tiny_run, tmp_path):
    """The file is written under a hidden temporary name and renamed when complete: a write
    that fails half-way (here metadata JSON cannot hold) leaves what was there."""
    trainer, params, _ = export.load_run(tiny_run)
    arrays = export.policy_arrays(trainer.network, params)
    meta = {**export.policy_metadata(trainer), "not_json": {1, 2}}
    out = tmp_path / "p.npz"
    out.write_bytes(b"the previous export")
    with pytest.raises(TypeError, match="not JSON serializable"):
        export.write_policy(arrays, meta, out, "npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.npz"]
    assert out.read_bytes() == b"the previous export"


def test_describe_names_every_value_of_a_frame(exported):
    trainer, _, _, _, npz, _ = exported
    meta = Policy.load(npz).metadata
    text = describe(meta)
    frame = [e for e in meta["observation"]["entries"] if e.get("frame", 0) == 0]
    for e in frame:
        assert f"| {e['name']} |" in text
        assert e["name"] in meta["observation"]["quantities"] or e["name"].startswith("obstacle")
    rows = [r for r in text.splitlines() if r.startswith("| ") and not r.startswith("| index |")]
    covered = sum(
        int(r.split("|")[1].split("-")[-1]) - int(r.split("|")[1].split("-")[0]) + 1 for r in rows
    )
    assert covered == len(frame)


def test_a_robot_policy_runs_on_a_maze_file_with_its_own_sensors(tmp_path):
    """Another env id (a maze file) gets the policy's observation fields: the generalist's
    network fits RobotMaze-v0 without naming its sensors."""
    trainer = Trainer(CASES["robot-generalist"])
    params = random_params(trainer, jax.random.key(0))
    arrays = export.policy_arrays(trainer.network, params)
    npz = export.write_policy(arrays, export.policy_metadata(trainer), tmp_path / "p.npz", "npz")
    policy = Policy.load(npz)
    maze = str(Path(__file__).resolve().parents[1] / "examples/mazes/rooms.txt")
    env_id, kwargs = export.env_for(policy, "RobotMaze-v0", {"maze_file": maze})
    assert kwargs["num_lasers"] == 32 and kwargs["waypoint_distance"] == 1.0
    assert kwargs["backend"] == "kinematic" and kwargs["obs_absolute"] is False
    on_maze, stacked = export.to_trainer(policy, env_id, {"maze_file": maze})
    assert on_maze.env.name == "RobotMaze-v0" and on_maze.obs_size == trainer.obs_size
    assert jax.tree.leaves(stacked)[0].shape[0] == 1  # one seed
    # an override that changes the observation is refused in one line
    with pytest.raises(ValueError, match="--env-arg num_lasers=8: .* with num_lasers=32;"):
        export.to_trainer(policy, env_id, {"maze_file": maze, "num_lasers": 8})


def test_a_bfloat16_network_is_exported_in_float32_and_says_so(tmp_path):
    """RobotNav-v0's preset trains with bfloat16 matrix products: the export computes in
    float32, records the trained dtype, and equals the float32 network of the same params."""
    config = TrainConfig(
        env="RobotSimple-v0",
        env_kwargs={"backend": "kinematic"},
        hidden_sizes=(32,),
        compute_dtype="bfloat16",
    )
    trainer = Trainer(config)
    params = random_params(trainer, jax.random.key(1))
    meta = export.policy_metadata(trainer)
    assert meta["network"]["trained_compute_dtype"] == "bfloat16"
    npz = export.write_policy(
        export.policy_arrays(trainer.network, params), meta, tmp_path / "p.npz", "npz"
    )
    float32, _ = export.to_trainer(Policy.load(npz))
    assert float32.network.compute_dtype == "float32"
    obs = observations(trainer, 1024)
    q_jax = np.asarray(float32.network.apply(params, jnp.asarray(obs)))
    assert_same_policy(q_jax, Policy.load(npz).q_values(obs), Policy.load(npz).act(obs))


# ------------------------------------------------------------------ a network with memory
MEMORY_CASE = TrainConfig(
    env="GridMaze-Random-v0",
    env_kwargs={"size": 7, "num_layouts": 8, "goals_per_layout": 4},
    hidden_sizes=(32,),
    algo="pqn",
    layer_norm=True,
    memory=16,
)


@pytest.fixture(scope="module")
def exported_memory(tmp_path_factory):
    """``(trainer, params, npz path, onnx path)`` of a random network with a GRU."""
    trainer = Trainer(MEMORY_CASE)
    params = random_params(trainer, jax.random.key(4))
    arrays = export.policy_arrays(trainer.network, params)
    metadata = export.policy_metadata(trainer, {"test": "memory"})
    out = tmp_path_factory.mktemp("memory")
    npz = export.write_policy(arrays, metadata, out / "policy.npz", "npz")
    onnx_path = export.write_policy(arrays, metadata, out / "policy.onnx", "onnx")
    return trainer, params, npz, onnx_path


def test_exported_memory_acts_as_the_package_over_whole_episodes(exported_memory):
    """The numpy policy and the ONNX graph, each carrying its own state, give the package's
    greedy actions (``Trainer.greedy_policy``) at every step of 16 whole episodes."""
    trainer, params, npz, onnx_path = exported_memory
    env, env_params, n = trainer.env, trainer.env_params, 16
    policy = Policy.load(npz)
    assert policy.memory == 16 and policy.metadata["format_version"] == 2
    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    greedy = trainer.greedy_policy(params)

    @jax.jit
    def package(h, obs):  # the Q-values and the greedy policy's step
        return trainer.network.apply(params, obs, h)[0], greedy.step(h, None, obs)

    env_step = jax.jit(jax.vmap(env.step_no_reset, in_axes=(0, 0, 0, None)))
    keys = jax.random.split(jax.random.key(6), n)
    obs, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, env_params)
    hidden, onnx_hidden = greedy.start(n), np.zeros((n, 16), np.float32)
    ended, steps = np.zeros(n, bool), 0
    while not ended.all():
        q_jax, (hidden, action) = jax.device_get(package(hidden, obs))
        q = policy.q_values(np.asarray(obs))
        chosen = policy.act(np.asarray(obs))
        q_onnx, onnx_action, onnx_hidden = session.run(
            ["q_values", "action", "next_hidden"],
            {"obs": np.asarray(obs, np.float32), "hidden": onnx_hidden},
        )
        live = ~ended
        assert_same_policy(q_jax[live], q[live], chosen[live])
        assert_same_policy(q_jax[live], q_onnx[live], onnx_action[live])
        np.testing.assert_array_equal(chosen, action)
        np.testing.assert_allclose(policy.hidden, onnx_hidden, rtol=1e-5, atol=1e-6)
        keys = jax.random.split(jax.random.key(steps), n)
        obs, state, _, terminated, truncated, _ = env_step(keys, state, action, env_params)
        ended |= np.asarray(terminated | truncated)
        steps += 1
    assert steps > 3  # episodes of several steps: the state carried through them
    # an episode's start forgets the last one: a reset row is a fresh policy's
    fresh = Policy.load(npz)
    policy.reset(np.arange(n) < 4)
    np.testing.assert_array_equal(policy.q_values(obs)[:4], fresh.q_values(obs[:4]))
    assert not np.allclose(policy.q_values(obs)[4:], fresh.q_values(obs[4:]))
    with pytest.raises(ValueError, match="reset"):
        policy.act(np.asarray(obs[:3]))
    assert "a GRU of 16 units" in describe(policy.metadata)


def test_flax_params_invert_policy_arrays_of_a_network_with_memory(exported_memory):
    trainer, params, npz, _ = exported_memory
    policy = Policy.load(npz)
    back = export.flax_params(policy.arrays, policy.network)
    jax.tree.map(np.testing.assert_array_equal, back, params)
    trainer_back, params_back = export.to_trainer(policy)
    assert trainer_back.network.memory == 16
    jax.tree.map(np.testing.assert_array_equal, jax.tree.map(lambda x: x[0], params_back), params)
