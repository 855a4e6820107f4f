"""The fused LayerNorm + ReLU (jaxnav.agents.layer_norm): flax's function and gradient, in jnp
and as Pallas kernels (interpreted on this CPU), a float32-accurate gradient in bfloat16, and
QNetwork's three implementations sharing one parameter tree."""

from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_TRAIN
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from jaxnav.agents import dqn, layer_norm
from jaxnav.agents.layer_norm import kernel_fits, layer_norm_relu
from jaxnav.train import Trainer

ROWS, WIDTH = 32, 128


def flax_layer_norm_relu(z, dense_bias, scale, bias):
    ln = nn.LayerNorm(dtype=z.dtype)
    return nn.relu(
        ln.apply({"params": {"scale": scale, "bias": bias}}, z + dense_bias.astype(z.dtype))
    )


def inputs(rows=ROWS, width=WIDTH, dtype=jnp.float32, seed=0):
    k = jax.random.split(jax.random.key(seed), 5)
    z = (3.0 * jax.random.normal(k[0], (rows, width)) + 1.0).astype(dtype)
    dense_bias = 0.1 * jax.random.normal(k[1], (width,))
    scale = 1.0 + 0.2 * jax.random.normal(k[2], (width,))
    bias = 0.1 * jax.random.normal(k[3], (width,))
    cotangent = jax.random.normal(k[4], (rows, width))
    return (z, dense_bias, scale, bias), cotangent


def value_and_grads(fn, args, cotangent):
    """The output as a gradient step computes it (the forward under differentiation) and the
    four inputs' gradients of ``(output * cotangent).sum()``."""
    out, vjp = jax.vjp(fn, *args)
    return out, vjp(cotangent.astype(out.dtype))


def uses_kernel(fn, args) -> bool:
    return "pallas_call" in str(jax.make_jaxpr(jax.grad(lambda *a: fn(*a).sum()))(*args))


def assert_computes_flax_layer_norm_relu(fn, args, cotangent):
    out, grads = value_and_grads(fn, args, cotangent)
    want_out, want_grads = value_and_grads(flax_layer_norm_relu, args, cotangent)
    np.testing.assert_allclose(out, want_out, atol=2e-6)
    for got, want in zip(grads, want_grads, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * np.abs(want).max())


@pytest.mark.parametrize(
    "pallas, blocks",
    [(False, None), (True, None), (True, layer_norm.Blocks(8, 4, 2, 2)),
     (True, layer_norm.Blocks(4, 4, 3, 1))],
    ids=["jnp", "pallas", "pallas-2-trips", "pallas-4-trips"],
)  # fmt: skip
def test_fused_op_is_flax_layer_norm_then_relu_with_its_gradient(pallas, blocks, monkeypatch):
    """``blocks``: each kernel instance loops over several blocks of rows (the backward's
    column sums of all of them added up before they are written): 32 rows in blocks of 8 over
    at most 2 instances, 2 blocks each; in blocks of 4 over at most 3, so 2 instances of 4
    blocks (an instance count that divides the blocks). None: the tables' blocks, one an
    instance at these 32 rows."""
    if blocks is not None:
        monkeypatch.setitem(layer_norm.BACKWARD_BLOCKS, WIDTH, blocks)
        monkeypatch.setitem(layer_norm.FORWARD_BLOCKS, WIDTH, blocks)
    args, cotangent = inputs()
    fused = lambda *a: layer_norm_relu(*a, pallas=pallas)  # noqa: E731
    assert kernel_fits(ROWS, WIDTH) and uses_kernel(fused, args) == pallas
    if blocks is not None:
        jaxpr = str(jax.make_jaxpr(jax.grad(lambda *a: fused(*a).sum()))(*args))
        assert jaxpr.count("grid=(2,)") == 2, "both kernels over 2 instances"
    assert_computes_flax_layer_norm_relu(fused, args, cotangent)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.bfloat16])
def test_calls_without_a_gradient_are_the_jnp_form_with_the_kernels_values(dtype):
    """Acting and evaluation passes take no gradient: they run the jnp form, which XLA fuses
    with the products around it, and give what the forward kernel of a gradient step gives."""
    args, _ = inputs(dtype=dtype)
    fused = lambda *a: layer_norm_relu(*a, pallas=True)  # noqa: E731
    differentiated = lambda *a: jax.vjp(fused, *a)[0]  # noqa: E731
    assert "pallas_call" not in str(jax.make_jaxpr(fused)(*args))
    assert "pallas_call" in str(jax.make_jaxpr(differentiated)(*args))
    # XLA's fusion may sum a row in another order than the kernel: a rounding step apart
    step = 2e-6 if dtype == jnp.float32 else 8e-3
    np.testing.assert_allclose(
        fused(*args).astype(jnp.float32),
        differentiated(*args).astype(jnp.float32),
        rtol=step,
        atol=step,
    )


def test_bfloat16_gradient_is_float32_accurate():
    """In bfloat16 the op stores z, its output and z's gradient in bfloat16 but computes in
    float32: its gradients stay within 1% of float32 math on the same inputs, where flax's
    LayerNorm in bfloat16 (its gradient carried in bfloat16) is further off."""
    args, cotangent = inputs(dtype=jnp.bfloat16)
    exact = value_and_grads(
        flax_layer_norm_relu, (args[0].astype(jnp.float32), *args[1:]), cotangent
    )[1]

    def error(fn):
        grads = value_and_grads(fn, args, cotangent)[1]
        return max(
            float(jnp.abs(g.astype(jnp.float32) - e).max() / jnp.abs(e).max())
            for g, e in zip(grads, exact, strict=True)
        )

    fused = error(lambda *a: layer_norm_relu(*a, pallas=True))
    assert fused < 1e-2
    assert fused == error(layer_norm_relu)  # the kernels compute the jnp form's math
    assert error(flax_layer_norm_relu) > 5 * fused
    assert layer_norm_relu(*args).dtype == jnp.bfloat16


def test_narrowest_kernel_width_computes_flax_layer_norm_relu():
    """Width 64 (the last hidden layer of the grid's network) with the table's blocks: 64
    rows a block, two blocks."""
    rows = 2 * layer_norm.FORWARD_BLOCKS[64].rows
    args, cotangent = inputs(rows, 64)
    fused = lambda *a: layer_norm_relu(*a, pallas=True)  # noqa: E731
    assert kernel_fits(rows, 64) and uses_kernel(fused, args)
    assert_computes_flax_layer_norm_relu(fused, args, cotangent)


@pytest.mark.parametrize("rows, width", [(12, 128), (32, 96), (32, 32), (96, 64)])
def test_shapes_the_kernels_do_not_take_run_the_jnp_form(rows, width):
    args, cotangent = inputs(rows, width)
    assert not kernel_fits(rows, width)
    fused = lambda *a: layer_norm_relu(*a, pallas=True)  # noqa: E731
    assert not uses_kernel(fused, args)
    assert_computes_flax_layer_norm_relu(fused, args, cotangent)


def test_kernels_under_vmap_over_seeds_compute_each_seed_alone():
    seeds = [inputs(seed=s) for s in range(3)]
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *[a for a, _ in seeds])
    cotangents = jnp.stack([c for _, c in seeds])
    fused = lambda *a: layer_norm_relu(*a, pallas=True)  # noqa: E731
    batched = jax.vmap(lambda a, c: value_and_grads(fused, a, c))(stacked, cotangents)
    for s, (args, cotangent) in enumerate(seeds):
        alone = value_and_grads(fused, args, cotangent)
        for b, a in zip(jax.tree.leaves(batched), jax.tree.leaves(alone), strict=True):
            np.testing.assert_allclose(b[s], a, rtol=1e-6, atol=1e-6)


def mesh_of(seeds: int, envs: int) -> Mesh:
    return Mesh(np.array(jax.devices()[: seeds * envs]).reshape(seeds, envs), ("seeds", "envs"))


@pytest.mark.parametrize("rows", [64, 30, 31], ids=["kernels", "jnp-per-device", "uneven"])
def test_rows_split_over_devices_compute_flax_layer_norm_relu(rows):
    """Over two devices each computes its own rows (through the kernels where they fit) and
    the parameters' gradients are the sums over both devices' rows."""
    mesh = mesh_of(1, 2)
    args, cotangent = inputs(rows)
    split = lambda *a: layer_norm_relu(*a, pallas=True, mesh=mesh, rows_axis="envs")  # noqa: E731
    z = jax.device_put(args[0], NamedSharding(mesh, P("envs") if rows % 2 == 0 else P()))
    args = (z, *args[1:])
    assert uses_kernel(split, args) == (rows == 64)
    assert_computes_flax_layer_norm_relu(jax.jit(split), args, cotangent)
    out = jax.jit(split)(*args)
    if rows % 2 == 0:  # the rows stay where they were: no device computes the other's
        assert out.sharding.is_equivalent_to(NamedSharding(mesh, P("envs")), out.ndim)


def test_seeds_split_over_devices_compute_each_seed_alone():
    """Under ``vmap(spmd_axis_name=...)`` over seeds, a seed a device: the same values and
    gradients as each seed alone on one device."""
    mesh = mesh_of(2, 1)
    seeds = [inputs(seed=s) for s in range(2)]
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *[a for a, _ in seeds])
    stacked = jax.device_put(stacked, NamedSharding(mesh, P("seeds")))
    cotangents = jnp.stack([c for _, c in seeds])
    split = lambda *a: layer_norm_relu(*a, pallas=True, mesh=mesh, rows_axis="envs")  # noqa: E731
    per_seed = lambda a, c: value_and_grads(split, a, c)  # noqa: E731
    batched = jax.jit(jax.vmap(per_seed, spmd_axis_name="seeds"))(stacked, cotangents)
    for s, (args, cotangent) in enumerate(seeds):
        alone = value_and_grads(lambda *a: layer_norm_relu(*a, pallas=True), args, cotangent)
        for b, a in zip(jax.tree.leaves(batched), jax.tree.leaves(alone), strict=True):
            np.testing.assert_allclose(b[s], a, rtol=1e-6, atol=1e-6)


@pytest.mark.slow  # compiles both implementations' forward and backward passes
@pytest.mark.parametrize("dueling", [True, False], ids=["dueling", "plain"])
def test_network_implementations_share_parameters_and_compute_alike(dueling):
    """Checkpoints and exports read one parameter tree whichever implementation trained it."""
    obs = jax.random.normal(jax.random.key(1), (ROWS, 11))
    nets = {
        impl: dqn.QNetwork(
            4, hidden_sizes=(WIDTH, 64), dueling=dueling, layer_norm=True, norm_impl=impl
        )
        for impl in dqn.NORM_IMPLS
    }
    params = {impl: net.init(jax.random.key(0), obs) for impl, net in nets.items()}
    for p in params.values():
        jax.tree.map(np.testing.assert_array_equal, p, params["flax"])
    q = {impl: net.apply(params["flax"], obs) for impl, net in nets.items()}
    cotangent = jax.random.normal(jax.random.key(2), q["flax"].shape)
    grads = {
        impl: jax.grad(lambda p, net=net: (net.apply(p, obs) * cotangent).sum())(params["flax"])
        for impl, net in nets.items()
    }
    for impl in ("fused", "pallas"):
        np.testing.assert_allclose(q[impl], q["flax"], rtol=1e-5, atol=1e-5)
        # every parameter, the value and advantage heads' among them, learns alike
        jax.tree.map(
            lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5),
            grads[impl],
            grads["flax"],
        )
    with pytest.raises(ValueError, match="norm_impl='triton'"):
        dqn.QNetwork(4, layer_norm=True, norm_impl="triton").init(jax.random.key(0), obs)


def test_trainer_fuses_only_when_asked_and_uses_kernels_only_on_gpus():
    pqn = dataclasses.replace(TINY_TRAIN, algo="pqn", layer_norm=True)
    assert Trainer.norm_impl(pqn) == "flax"
    fused = dataclasses.replace(pqn, fused_layer_norm=True)
    on_gpu = jax.default_backend() == "gpu"
    assert Trainer.norm_impl(fused) == ("pallas" if on_gpu else "fused")
    two = dataclasses.replace(fused, devices=2)
    assert Trainer.norm_impl(two) == ("pallas" if on_gpu else "fused")
    assert Trainer(two).learner_network.mesh.size == 2
    assert Trainer(fused).learner_network.mesh is None and Trainer(two).network.mesh is None
    # the flag says how a LayerNorm is computed; without one there is nothing to fuse
    assert Trainer.norm_impl(dataclasses.replace(fused, layer_norm=False)) == "flax"
