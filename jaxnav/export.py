"""Export a trained policy off the simulator: ``python -m jaxnav.export RUN --format onnx|npz``.

One file holds everything a robot needs to run the policy: the network's weights and the
metadata (``policy_metadata``): the observation layout (every input value by name, with its
scale and clip), the action meanings (speeds, or grid moves), the sensor configuration (beams,
field of view, range, frames, control period), the env id and kwargs, and where it came from.

- ``npz``: the arrays under plain names and the metadata as JSON (``jaxnav.deploy.policy``
  documents the layout and runs it with numpy alone), with the SHA-256 of every array.
- ``onnx``: the same network as an ONNX graph written from the trained parameters (MatMul,
  Add, LayerNormalization, Relu, the GRU's Sigmoid and Tanh, the dueling combination, ArgMax;
  input ``obs`` float32 [batch, obs_size], outputs ``q_values`` and ``action``; a network with
  memory also takes its state ``hidden`` float32 [batch, memory], zeros at an episode's
  start, and returns the next one, ``next_hidden``), the metadata as the model's
  ``metadata_props["jaxnav"]`` (JSON) and the SHA-256 of every initializer and of that
  metadata as ``metadata_props["checksum"]``, checked by ``load_onnx``. Needs the ``onnx``
  package (``pip install 'jaxnav[export]'``); run it with ``onnxruntime`` or any ONNX runtime
  of opset 17.

The grid's compact ``index`` observations stay compact: the exported network one-hot encodes
the values ``network.onehot_sizes`` marks, as ``QNetwork`` does. A run trained with bfloat16
matrix products is exported in float32 (its Q-values then differ by bfloat16's rounding).
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxnav import run_dir
from jaxnav.agents.dqn import QNetwork, check_input_fits, flax_params
from jaxnav.config import TrainConfig
from jaxnav.deploy.policy import (
    CHECKSUM_KEY,
    FORMAT,
    FORMAT_VERSION,
    GRU_GATES,
    Policy,
    array_checksums,
    verify_checksums,
)
from jaxnav.safe_io import WriteFault, atomic_output, check_output_file
from jaxnav.version import __version__

FORMATS = ("npz", "onnx")
ONNX_OPSET = 17  # LayerNormalization's first opset
ONNX_IR_VERSION = 8  # the oldest IR of opset 17: runtimes back to onnxruntime 1.14 read it
LAYER_NORM_EPSILON = 1e-6  # flax.linen.LayerNorm's default, which QNetwork uses
METADATA_KEY = "jaxnav"


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.generic,)):
        return value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


def policy_metadata(trainer: Any, source: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything but the weights: network, observation layout, actions, sensors, env."""
    config: TrainConfig = trainer.config
    env, env_params = trainer.env, trainer.env_params
    net = trainer.network
    network = {
        "obs_size": int(trainer.obs_size),
        "onehot_sizes": None if net.onehot_sizes is None else list(net.onehot_sizes),
        "hidden_sizes": list(net.hidden_sizes),
        "dueling": bool(net.dueling),
        "layer_norm": bool(net.layer_norm),
        "layer_norm_epsilon": LAYER_NORM_EPSILON,
        "num_actions": int(net.num_actions),
        "trained_compute_dtype": net.compute_dtype,
        "input": "float32 [batch, obs_size]: the env's observation as float32",
        "output": f"{trainer.algorithm.outputs} [batch, num_actions]; the policy takes the "
        "first largest",
    }
    if net.memory:  # (absent without: the files of feed-forward networks stay as they were)
        network["memory"] = int(net.memory)
        network["hidden"] = (
            "float32 [batch, memory]: the GRU's state, zeros at an episode's start; each step "
            "reads it and returns the next"
        )
    env_config = getattr(env, "config", None)
    return _jsonable(
        {
            "format": FORMAT,
            # a reader of version 1 would drop a recurrent network's memory
            "format_version": FORMAT_VERSION if net.memory else 1,
            "env_id": config.env,
            "env_kwargs": dict(config.env_kwargs),
            "env_config": None if env_config is None else _config_dict(env_config),
            "algo": config.algo,
            "network": network,
            "observation": env.observation_layout(env_params),
            "actions": env.action_layout(),
            "sensors": env.sensor_layout(),
            "source": {"jaxnav_version": __version__, **(source or {})},
        }
    )


def _config_dict(config: Any) -> dict[str, Any]:
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}


# ------------------------------------------------------------------ weights
def policy_arrays(network: QNetwork, params: Any) -> dict[str, np.ndarray]:
    """The network's parameters (one seed, flax's tree) under the plain names of
    ``jaxnav.deploy.policy``, as float32 numpy arrays."""
    p = jax.device_get(params)["params"]
    out = {}
    for i in range(len(network.hidden_sizes)):
        out[f"dense{i}_kernel"] = p[f"Dense_{i}"]["kernel"]
        out[f"dense{i}_bias"] = p[f"Dense_{i}"]["bias"]
        if network.layer_norm:
            out[f"norm{i}_scale"] = p[f"LayerNorm_{i}"]["scale"]
            out[f"norm{i}_bias"] = p[f"LayerNorm_{i}"]["bias"]
    for gate, biased in GRU_GATES.items() if network.memory else ():
        out[f"gru_{gate}_kernel"] = p["memory"][gate]["kernel"]
        if biased:
            out[f"gru_{gate}_bias"] = p["memory"][gate]["bias"]
    if network.dueling:
        for head in ("value", "advantage"):
            out[f"{head}_kernel"], out[f"{head}_bias"] = p[head]["kernel"], p[head]["bias"]
    else:
        last = p[f"Dense_{len(network.hidden_sizes)}"]
        out["head_kernel"], out["head_bias"] = last["kernel"], last["bias"]
    return {k: np.asarray(v, np.float32) for k, v in out.items()}


def env_for(
    policy: Policy, env_id: str | None = None, overrides: dict[str, Any] | None = None
) -> tuple[str, dict[str, Any]]:
    """``(env id, env kwargs)`` to run ``policy`` on (``run_dir.policy_env``): its own env with
    ``overrides`` on its kwargs, or the env ``env_id`` with the policy's carried fields
    (``run_dir.CARRIED_FIELDS``) and ``overrides``."""
    meta = policy.metadata
    trained = meta.get("env_config") or {}
    own = meta["env_id"], meta["env_kwargs"]
    return run_dir.policy_env(*own, trained, env_id, dict(overrides or {}))


def to_trainer(
    policy: Policy, env_id: str | None = None, overrides: dict[str, Any] | None = None
) -> tuple[Any, Any]:
    """``(trainer, params)`` to run an exported policy in the simulator with JAX
    (``jaxnav.evaluate``, ``jaxnav.render``): its network on the env of ``env_for``, the
    parameters stacked as one seed's; ``ValueError`` where that env's observations do not fit
    the network."""
    from jaxnav.train import Trainer

    net = policy.network
    env_id, kwargs = env_for(policy, env_id, overrides)
    # the network as trained; TrainConfig's defaults for the rest, which acting never reads
    # (with memory an algorithm that trains one)
    memory = int(net.get("memory", 0))
    config = TrainConfig(
        env=env_id,
        env_kwargs=kwargs,
        hidden_sizes=tuple(net["hidden_sizes"]),
        dueling=net["dueling"],
        layer_norm=net["layer_norm"],
        memory=memory,
        **({"algo": "pqn"} if memory else {}),
    )
    trainer = Trainer(config)
    onehot = net["onehot_sizes"]
    want = (net["obs_size"], None if onehot is None else tuple(onehot))
    check_input_fits(env_id, trainer.network_input, want)
    params = flax_params(policy.arrays, net)
    return trainer, jax.tree.map(lambda x: x[None], params)


def load_pretrained(
    name: str, env_id: str | None = None, overrides: dict[str, Any] | None = None
) -> tuple[TrainConfig, Any, Any]:
    """``(config, trainer, params)`` of the shipped policy ``name`` (``jaxnav.pretrained``) on
    its own env or on ``env_id`` (``to_trainer``), as ``run_dir.load_run_on`` gives a run's."""
    from jaxnav import pretrained

    trainer, params = to_trainer(pretrained.load(name), env_id, overrides)
    return trainer.config, trainer, params


# ------------------------------------------------------------------ ONNX
def onnx_model(arrays: dict[str, np.ndarray], metadata: dict[str, Any]) -> Any:
    """The network as an ``onnx.ModelProto`` (opset 17), metadata in ``metadata_props``."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    net = metadata["network"]
    nodes: list[Any] = []
    weights: list[Any] = []

    def const(name: str, value: np.ndarray) -> str:
        weights.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    def node(op: str, inputs: list[str], output: str, **attrs: Any) -> str:
        nodes.append(helper.make_node(op, inputs, [output], name=output, **attrs))
        return output

    x = "obs"
    if net["onehot_sizes"] is not None:  # jaxnav.agents.dqn.expand_onehot, column by column
        parts = []
        for i, n in enumerate(net["onehot_sizes"]):
            column = node("Gather", [x, const(f"column{i}", np.array([i], np.int64))],
                          f"obs_{i}", axis=1)  # fmt: skip
            if n:
                index = node("Cast", [column], f"obs_{i}_int", to=TensorProto.INT32)
                categories = const(f"categories{i}", np.arange(n, dtype=np.int32))
                hit = node("Equal", [index, categories], f"obs_{i}_is")
                column = node("Cast", [hit], f"obs_{i}_onehot", to=TensorProto.FLOAT)
            parts.append(column)
        x = node("Concat", parts, "features", axis=1)
    for i in range(len(net["hidden_sizes"])):
        x = node("MatMul", [x, const(f"dense{i}_kernel", arrays[f"dense{i}_kernel"])], f"h{i}_mm")
        x = node("Add", [x, const(f"dense{i}_bias", arrays[f"dense{i}_bias"])], f"h{i}_dense")
        if net["layer_norm"]:
            scale = const(f"norm{i}_scale", arrays[f"norm{i}_scale"])
            bias = const(f"norm{i}_bias", arrays[f"norm{i}_bias"])
            x = node("LayerNormalization", [x, scale, bias], f"h{i}_norm", axis=-1,
                     epsilon=float(net["layer_norm_epsilon"]))  # fmt: skip
        x = node("Relu", [x], f"h{i}")
    memory = int(net.get("memory", 0))
    if memory:  # flax's GRUCell: r, z gates; n = tanh(in + r (hn)); (1 - z) n + z h
        gates = {}
        for gate, biased in GRU_GATES.items():
            read = x if gate[0] == "i" else "hidden"
            kernel = const(f"gru_{gate}_kernel", arrays[f"gru_{gate}_kernel"])
            gates[gate] = node("MatMul", [read, kernel], f"gru_{gate}_mm")
            if biased:
                bias = const(f"gru_{gate}_bias", arrays[f"gru_{gate}_bias"])
                gates[gate] = node("Add", [gates[gate], bias], f"gru_{gate}")
        r = node("Add", [gates["ir"], gates["hr"]], "gru_r_sum")
        r = node("Sigmoid", [r], "gru_r")
        z = node("Add", [gates["iz"], gates["hz"]], "gru_z_sum")
        z = node("Sigmoid", [z], "gru_z")
        n = node("Mul", [r, gates["hn"]], "gru_r_hn")
        n = node("Tanh", [node("Add", [gates["in"], n], "gru_n_sum")], "gru_n")
        keep = node("Sub", [const("one", np.ones((), np.float32)), z], "gru_1_minus_z")
        new = node("Mul", [keep, n], "gru_new")
        old = node("Mul", [z, "hidden"], "gru_old")
        x = node("Add", [new, old], "next_hidden")
    if net["dueling"]:
        v = node("MatMul", [x, const("value_kernel", arrays["value_kernel"])], "value_mm")
        v = node("Add", [v, const("value_bias", arrays["value_bias"])], "value")
        a = node("MatMul", [x, const("advantage_kernel", arrays["advantage_kernel"])], "adv_mm")
        a = node("Add", [a, const("advantage_bias", arrays["advantage_bias"])], "advantage")
        mean = node("ReduceMean", [a], "advantage_mean", axes=[1], keepdims=1)
        q = node("Add", [v, a], "value_plus_advantage")  # V + A - mean(A), QNetwork's order
        node("Sub", [q, mean], "q_values")
    else:
        q = node("MatMul", [x, const("head_kernel", arrays["head_kernel"])], "head_mm")
        node("Add", [q, const("head_bias", arrays["head_bias"])], "q_values")
    # the first largest Q-value, as jnp.argmax
    node("ArgMax", ["q_values"], "action", axis=1, keepdims=0, select_last_index=0)
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", net["obs_size"]])]
    outputs = [
        helper.make_tensor_value_info("q_values", TensorProto.FLOAT, ["batch", net["num_actions"]]),
        helper.make_tensor_value_info("action", TensorProto.INT64, ["batch"]),
    ]
    if memory:
        for names, name in ((inputs, "hidden"), (outputs, "next_hidden")):
            names.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, ["batch", memory]))
    graph = helper.make_graph(nodes, "jaxnav_policy", inputs, outputs, initializer=weights)
    model = helper.make_model(
        graph,
        producer_name="jaxnav",
        producer_version=__version__,
        opset_imports=[helper.make_opsetid("", ONNX_OPSET)],
        ir_version=ONNX_IR_VERSION,
        doc_string=f"jaxnav policy for {metadata['env_id']}: Q-values and the greedy action",
    )
    text = json.dumps(metadata)
    checksums = json.dumps(array_checksums(onnx_arrays(model, text)))
    helper.set_model_props(model, {METADATA_KEY: text, CHECKSUM_KEY: checksums})
    onnx.checker.check_model(model, full_check=True)
    return model


def onnx_arrays(model: Any, metadata: str) -> dict[str, np.ndarray]:
    """Every initializer of ``model`` and its jaxnav ``metadata`` text, as the arrays its
    checksums cover."""
    from onnx import numpy_helper

    arrays = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    return {**arrays, METADATA_KEY: np.array(metadata)}


def load_onnx(path: str | os.PathLike) -> tuple[Any, dict[str, Any]]:
    """``(onnx.ModelProto, jaxnav metadata)`` of an exported ONNX policy, its initializers and
    metadata checked against the checksums written with them (files exported before
    checksums load unchecked); ``ValueError`` (one line naming the file) for a damaged one."""
    import onnx

    if not os.path.isfile(path):  # a FIFO would block, a directory is no model
        raise ValueError(f"{path}: not a jaxnav policy file (not a regular file)")
    try:
        model = onnx.load(os.fspath(path))
        props = {p.key: p.value for p in model.metadata_props}
        arrays = onnx_arrays(model, props.get(METADATA_KEY, ""))
    except Exception as e:  # noqa: BLE001 (protobuf raises several kinds for a damaged file)
        raise ValueError(f"{path}: truncated or damaged ONNX file ({type(e).__name__})") from None
    if METADATA_KEY not in props:
        raise ValueError(f"{path}: not a jaxnav policy (no {METADATA_KEY!r} metadata)")
    if CHECKSUM_KEY in props:
        verify_checksums(path, arrays, props[CHECKSUM_KEY])
    try:
        return model, json.loads(props[METADATA_KEY])
    except ValueError as e:
        raise ValueError(f"{path}: not a jaxnav policy ({e})") from None


def onnx_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The jaxnav metadata of an exported ONNX model (checked as ``load_onnx``)."""
    return load_onnx(path)[1]


# ------------------------------------------------------------------ writing
def write_policy(
    arrays: dict[str, np.ndarray], metadata: dict[str, Any], out: Path, fmt: str
) -> Path:
    """Write ``fmt`` (npz or onnx) to ``out`` through a hidden temporary file renamed at the
    end, so ``out`` is never half written."""
    if fmt not in FORMATS:
        raise ValueError(f"--format {fmt}: must be one of {', '.join(FORMATS)}")
    if fmt == "onnx":
        payload = onnx_model(arrays, metadata).SerializeToString()  # built (and checked) first
    with atomic_output(out) as tmp, open(tmp, "wb") as f:
        if fmt == "npz":
            stored = {**arrays, "metadata": np.array(json.dumps(metadata))}
            checksums = np.array(json.dumps(array_checksums(stored)))
            np.savez_compressed(f, **stored, **{CHECKSUM_KEY: checksums})
        else:
            f.write(payload)
    return out


def load_run(run: Path, run_seed: int | None = None) -> tuple[Any, Any, int]:
    """``(trainer, params of one seed, that seed)`` of the trained run directory ``run``
    (default: its first seed); ``ValueError`` for a directory that is not a complete run."""
    from jaxnav.train import Trainer

    config = run_dir.load_config(run)
    seeds = run_dir.seeds_of(config)
    seed = seeds[0] if run_seed is None else run_seed
    if seed not in seeds:
        raise ValueError(f"--run-seed {seed}: the run has seeds {seeds}")
    if not (run / "params").is_dir():
        raise ValueError(f"{run}: no trained parameters (params/); is the run complete?")
    trainer = Trainer(config)
    params = run_dir.load_trained_params(run, trainer)
    return trainer, jax.tree.map(lambda x: x[seeds.index(seed)], params), seed


def run_evaluation(run: Path, seed: int, seeds: list[int]) -> dict[str, Any] | None:
    """The run's own greedy evaluation of ``seed`` (summary.json), where there is one."""
    try:
        summary = json.loads((run / "summary.json").read_text())
        row = summary["trained_per_seed"][seeds.index(seed)]
    except (OSError, KeyError, IndexError, TypeError, ValueError):  # TypeError: not evaluated
        return None
    kept = {k: v for k, v in row.items() if isinstance(v, (int, float)) or v is None}
    # the training CLI evaluates on the episodes of seed 10,000 (runner.finish_run)
    return {"episodes": summary.get("eval_episodes"), "seed": 10_000, **kept}


def export_run(
    run: Path, fmt: str, out: Path | None = None, run_seed: int | None = None
) -> tuple[Path, dict[str, Any]]:
    """Export seed ``run_seed`` (default: the first) of the run directory ``run`` as ``fmt``
    to ``out`` (default ``RUN/policy.FMT``); ``(path written, metadata)``."""
    out = run / f"policy.{fmt}" if out is None else out
    check_out(out, fmt)
    trainer, params, seed = load_run(run, run_seed)
    source = {
        "run": os.fspath(run),
        "run_seed": seed,
        "train_config": run_dir.config_to_json(trainer.config),
        "run_evaluation": run_evaluation(run, seed, run_dir.seeds_of(trainer.config)),
    }
    metadata = policy_metadata(trainer, source)
    arrays = policy_arrays(trainer.network, params)
    return write_policy(arrays, metadata, out, fmt), metadata


def check_out(out: Path, fmt: str) -> None:
    """``ValueError`` before any work where ``fmt`` or ``out`` cannot be written."""
    if fmt not in FORMATS:
        raise ValueError(f"--format {fmt}: must be one of {', '.join(FORMATS)}")
    if out.suffix != f".{fmt}":
        raise ValueError(f"--out {out}: must end in .{fmt} for --format {fmt}")
    check_output_file(out)  # a link, a directory or a device is refused, not replaced
    if fmt == "onnx":
        try:
            import onnx  # noqa: F401
        except ImportError:
            raise ValueError(
                "--format onnx needs the onnx package: pip install 'jaxnav[export]'"
            ) from None


# ------------------------------------------------------------------ command line
def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    from jaxnav.cli import Parser, UsageError, fail, write_failed

    prog = "jaxnav.export"
    p = Parser(
        prog="python -m jaxnav.export",
        description="Write a trained run's policy as one self-contained file: the network "
        "and its metadata (observation layout, actions, sensors, env).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("run", type=Path, help="run directory written by jaxnav.train")
    p.add_argument("--format", choices=FORMATS, default="npz", help="npz (numpy) or onnx")
    p.add_argument("--out", type=Path, help="output file (default: RUN/policy.FORMAT)")
    p.add_argument("--run-seed", type=int, help="which trained seed (default: the run's first)")
    try:
        args = p.parse_args(argv)
        if not args.run.is_dir():
            why = "not a directory" if os.path.lexists(args.run) else "no such directory"
            raise ValueError(f"{args.run}: not a run directory ({why})")
        path, metadata = export_run(args.run, args.format, args.out, args.run_seed)
    except WriteFault as e:
        return write_failed(prog, e)
    except (UsageError, ValueError, FileNotFoundError) as e:
        return fail(prog, str(e))
    net = metadata["network"]
    size = path.stat().st_size
    print(
        f"wrote {path} ({size / 1024:,.0f} KiB): {metadata['env_id']}, "
        f"{net['obs_size']} inputs -> {'-'.join(map(str, net['hidden_sizes']))} -> "
        + (f"GRU {net['memory']} -> " if net.get("memory") else "")
        + f"{net['num_actions']} actions ({', '.join(a['name'] for a in metadata['actions'])})"
    )
    if net["trained_compute_dtype"] != "float32":
        print(
            f"note: trained with {net['trained_compute_dtype']} matrix products; the export "
            "computes in float32 (Q-values differ by that rounding)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
