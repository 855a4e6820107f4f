"""LayerNorm then ReLU as one op with a hand-written gradient: a PQN hidden layer's activation.

``layer_norm_relu(z, dense_bias, scale, bias)`` is ``relu(LayerNorm(z + dense_bias) * scale +
bias)`` over the last axis, where ``z`` is a Dense layer's product before its bias. It computes
what ``flax.linen.LayerNorm`` followed by ``nn.relu`` does, with the Dense bias folded in, but:

- statistics and the whole backward pass are float32 whatever ``z``'s dtype; only ``z``, the
  output and ``z``'s gradient are stored in it. flax's LayerNorm in bfloat16 carries its
  gradient in bfloat16, several times further from float32 math than this op's
  (``tests/test_layer_norm.py``);
- the backward pass keeps only ``z`` and two numbers a row (mean, reciprocal deviation), and
  recomputes the normalized values from them.

Two implementations of that math. ``pallas=True``: Pallas kernels (Triton on a GPU), one pass
over each block of rows forward (read ``z``, write the output and the residuals) and one
backward (read the output's gradient and ``z``, write ``z``'s gradient and each instance's
column sums of the three parameter gradients), where XLA's fusions of the same function read
each activation several times (with flax's LayerNorm, reductions took 44% of the GPU's kernel
time: ``profile_training_h100_RobotNav-v0_flax_norm``, docs/results-history.md). The
kernels run where a gradient is taken; a call without one (acting, evaluation) is the jnp form.
On a backend without Triton the kernels run in Pallas's interpreter (tests), and shapes they do
not take (``kernel_fits``) use the jnp form. ``pallas=False``: jnp, which XLA fuses as it can.

XLA cannot split a kernel's rows over devices. Given a ``mesh`` of several devices, the kernels
run on each device's rows (``shard_map``, the rows split over ``rows_axis``, a vmapped seed
axis over the vmap's ``spmd_axis_name``), and the parameter gradients are summed over the
devices; row counts the devices do not divide evenly take the jnp form.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxnav import backend

EPSILON = 1e-6  # flax.linen.LayerNorm's default
# widths the kernels take: a whole row is one block, Triton wants powers of two
KERNEL_WIDTHS = tuple(2**k for k in range(6, 12))  # 64 .. 2048


class Blocks(NamedTuple):
    """How a kernel covers its rows: blocks of ``rows`` rows, one at a time in an instance of
    ``warps`` GPU warps; at most ``instances`` instances, each looping over every
    ``instances``-th block (neighbouring instances read neighbouring rows) in a rolled loop
    whose loads Triton pipelines ``stages`` deep."""

    rows: int
    warps: int
    instances: int
    stages: int


# Chosen from each kernel timed alone (``python -m benchmarks.layer_norm_blocks``), then
# trained with (measured: docs/performance.md):
# - 1024 and 2048 at 16,384 rows, the RobotNav-v0 preset's minibatch: a few hundred instances
#   looping over small blocks, the next block's loads issued while the last one computes.
# - 512, 256 and 128 at 65,536 rows, GridMaze-v0's minibatch at 32,768 envs.
# - 64 at 65,536 rows: the grid network's last hidden layer, which took the jnp form before.
# Backward instances add up their blocks' column sums of the parameter gradients in registers
# and write them once: fewer instances, fewer partial sums to reduce.
FORWARD_BLOCKS: dict[int, Blocks] = {
    64: Blocks(64, 4, 2048, 2),
    128: Blocks(32, 4, 4096, 2),
    256: Blocks(16, 4, 1024, 2),
    512: Blocks(4, 4, 1024, 2),
    1024: Blocks(8, 4, 512, 2),
    2048: Blocks(8, 4, 2048, 1),
}
BACKWARD_BLOCKS: dict[int, Blocks] = {
    64: Blocks(64, 4, 1024, 2),
    128: Blocks(32, 4, 4096, 2),
    256: Blocks(16, 4, 1024, 2),
    512: Blocks(16, 4, 512, 2),
    1024: Blocks(2, 4, 512, 2),
    2048: Blocks(4, 4, 4096, 1),
}


def kernel_fits(rows: int, width: int) -> bool:
    """Whether the Pallas kernels take ``rows`` x ``width`` (else the jnp form runs)."""
    if width not in KERNEL_WIDTHS:
        return False
    return rows > 0 and all(rows % t[width].rows == 0 for t in (FORWARD_BLOCKS, BACKWARD_BLOCKS))


def layer_norm_relu(
    z: jax.Array,
    dense_bias: jax.Array,
    scale: jax.Array,
    bias: jax.Array,
    pallas: bool = False,
    mesh: Mesh | None = None,
    rows_axis: str | None = None,
) -> jax.Array:
    """``relu(LayerNorm(z + dense_bias) * scale + bias)`` over the last axis, in ``z``'s dtype.

    ``dense_bias``, ``scale`` and ``bias`` are [width] (float32 parameters); leading axes of
    ``z`` are rows. Differentiable in all four (a ``custom_vjp``). With ``pallas`` and a
    ``mesh`` of several devices, each device's rows (split over ``rows_axis``) go through the
    kernels on that device."""
    shape = z.shape
    rows = z.reshape(-1, shape[-1])
    split = pallas and mesh is not None and mesh.size > 1
    parts = mesh.shape[rows_axis] if split else 1
    if rows.shape[0] % parts:  # rows the devices do not divide evenly: the jnp form
        split = pallas = False
    kernel = pallas and kernel_fits(rows.shape[0] // parts, shape[-1])
    op = functools.partial(_layer_norm_relu, kernel)
    if split:
        # check_vma=False: pallas_call carries no varying-axes types; the transpose then sums
        # the parameters' cotangents over the devices, as replicated inputs need
        op = jax.shard_map(
            op,
            mesh=mesh,
            in_specs=(P(rows_axis), P(), P(), P()),
            out_specs=P(rows_axis),
            check_vma=False,
        )
    return op(rows, dense_bias, scale, bias).reshape(shape)


# ----------------------------------------------------------------------------- the math
# One forward and one backward for both forms: the jnp form calls them on all rows, the Pallas
# kernels on each block of rows they load, so the two compute the same function.
def _normalize(y: jax.Array, mean: jax.Array, rstd: jax.Array, scale, bias):
    xhat = (y - mean[:, None]) * rstd[:, None]
    return xhat, xhat * scale + bias


def _forward_math(z, dense_bias, scale, bias):
    """Rows of ``z`` -> (the float32 output, each row's mean and reciprocal deviation)."""
    y = z.astype(jnp.float32) + dense_bias
    mean = jnp.mean(y, axis=-1)
    rstd = jax.lax.rsqrt(jnp.mean(jnp.square(y - mean[:, None]), axis=-1) + EPSILON)
    _, pre = _normalize(y, mean, rstd, scale, bias)
    return jnp.maximum(pre, 0.0), mean, rstd


def _backward_math(grad, z, dense_bias, scale, bias, mean, rstd):
    """``z``'s gradient (float32) and, per row, the gradients of the Dense bias, the scale and
    the bias, which the caller sums over rows."""
    xhat, pre = _normalize(z.astype(jnp.float32) + dense_bias, mean, rstd, scale, bias)
    dpre = jnp.where(pre > 0, grad.astype(jnp.float32), 0.0)
    u = dpre * scale
    dz = rstd[:, None] * (
        u - u.mean(axis=-1, keepdims=True) - xhat * (u * xhat).mean(axis=-1, keepdims=True)
    )
    return dz, (dz, dpre * xhat, dpre)


def _forward_jnp(z, dense_bias, scale, bias):
    out, mean, rstd = _forward_math(z, dense_bias, scale, bias)
    return out.astype(z.dtype), mean, rstd


def _backward_jnp(grad, z, dense_bias, scale, bias, mean, rstd):
    dz, per_row = _backward_math(grad, z, dense_bias, scale, bias, mean, rstd)
    return (dz.astype(z.dtype), *(g.sum(0) for g in per_row))


# ----------------------------------------------------------------------------- Pallas kernels
def _each_block(rows_per_block: int, trips: int, body, init):
    """``body(rows, carry)`` on this instance's blocks in turn: blocks ``pid``, ``pid +
    instances``, ... (``trips`` of them), ``rows`` a ``pl.ds`` of ``rows_per_block``."""
    instances, pid = pl.num_programs(0), pl.program_id(0)

    def step(i, carry):
        start = pl.multiple_of((i * instances + pid) * rows_per_block, rows_per_block)
        return body(pl.ds(start, rows_per_block), carry)

    return jax.lax.fori_loop(0, trips, step, init)


def _forward_kernel(
    rows_per_block: int, trips: int,
    z_ref, dense_bias_ref, scale_ref, bias_ref, out_ref, mean_ref, rstd_ref,
):  # fmt: skip
    params = (dense_bias_ref[...], scale_ref[...], bias_ref[...])

    def block(rows, carry):
        out, mean, rstd = _forward_math(z_ref[rows, :], *params)
        out_ref[rows, :] = out.astype(out_ref.dtype)
        mean_ref[rows] = mean
        rstd_ref[rows] = rstd
        return carry

    _each_block(rows_per_block, trips, block, 0)


def _backward_kernel(
    rows_per_block: int, trips: int,
    grad_ref, z_ref, dense_bias_ref, scale_ref, bias_ref, mean_ref, rstd_ref, dz_ref, sums_ref,
):  # fmt: skip
    """``z``'s gradient of this instance's blocks, and their column sums of the three
    parameter gradients added up in the loop and written once to ``sums_ref`` (4 rows, the
    4th there for Triton's power-of-two blocks and not written)."""
    params = (dense_bias_ref[...], scale_ref[...], bias_ref[...])

    def block(rows, total):
        dz, per_row = _backward_math(
            grad_ref[rows, :], z_ref[rows, :], *params, mean_ref[rows], rstd_ref[rows]
        )
        dz_ref[rows, :] = dz.astype(dz_ref.dtype)
        return tuple(t + jnp.sum(g, axis=0) for t, g in zip(total, per_row, strict=True))

    zero = jnp.zeros(z_ref.shape[1:], jnp.float32)
    total = _each_block(rows_per_block, trips, block, (zero, zero, zero))
    for i, t in enumerate(total):
        sums_ref[pl.ds(i, 1), :] = t[None, :]


def _launch(blocks: Blocks, rows: int) -> tuple[int, int]:
    """(instances, trips): at most ``blocks.instances`` instances, each looping over the same
    number of blocks."""
    count = rows // blocks.rows
    trips = -(-count // blocks.instances)
    while count % trips:
        trips += 1
    return count // trips, trips


def _call(kernel, blocks: Blocks, args, out_shape, column_sums: bool, name: str):
    """``kernel(rows_per_block, trips, *refs)`` over ``args`` (the first [rows, width]) with
    ``blocks``: every array whole to each instance (it slices its own blocks); with
    ``column_sums``, a last output of 4 rows x width an instance."""
    rows, width = args[0].shape
    instances, trips = _launch(blocks, rows)
    interpret = backend.pallas_interpret()
    if interpret:
        params = None
    else:
        from jax.experimental.pallas import triton as pl_triton

        params = pl_triton.CompilerParams(num_warps=blocks.warps, num_stages=blocks.stages)

    def whole(shape) -> pl.BlockSpec:
        return pl.BlockSpec(shape, lambda i: (0,) * len(shape))

    out_specs = [whole(o.shape) for o in out_shape]
    if column_sums:
        out_shape = (*out_shape, jax.ShapeDtypeStruct((instances * 4, width), jnp.float32))
        out_specs.append(pl.BlockSpec((4, width), lambda i: (i, 0)))
    return pl.pallas_call(
        functools.partial(kernel, blocks.rows, trips),
        out_shape=tuple(out_shape),
        grid=(instances,),
        in_specs=[whole(a.shape) for a in args],
        out_specs=tuple(out_specs),
        interpret=interpret,
        compiler_params=params,
        name=name,
    )(*args)


def _forward_pallas(z, dense_bias, scale, bias):
    rows, width = z.shape
    per_row = jax.ShapeDtypeStruct((rows,), jnp.float32)
    return _call(
        _forward_kernel,
        FORWARD_BLOCKS[width],
        (z, dense_bias, scale, bias),
        (jax.ShapeDtypeStruct(z.shape, z.dtype), per_row, per_row),
        False,
        "layer_norm_relu_forward",
    )


def _backward_pallas(grad, z, dense_bias, scale, bias, mean, rstd):
    width = z.shape[1]
    dz, sums = _call(
        _backward_kernel,
        BACKWARD_BLOCKS[width],
        (grad.astype(z.dtype), z, dense_bias, scale, bias, mean, rstd),
        (jax.ShapeDtypeStruct(z.shape, z.dtype),),
        True,
        "layer_norm_relu_backward",
    )
    # one reduction over all instances for the three sums (three took 3x the launches)
    total = sums.reshape(-1, 4, width)[:, :3].sum(0)
    return (dz, total[0], total[1], total[2])


# ----------------------------------------------------------------------------- custom_vjp
@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _layer_norm_relu(kernel: bool, z, dense_bias, scale, bias):
    # Undifferentiated calls (acting, evaluation) keep no residuals: XLA fuses the jnp form with
    # the products around it, where the kernel is a launch of its own (docs/performance.md)
    return _forward_jnp(z, dense_bias, scale, bias)[0]


def _layer_norm_relu_fwd(kernel: bool, z, dense_bias, scale, bias):
    out, mean, rstd = (_forward_pallas if kernel else _forward_jnp)(z, dense_bias, scale, bias)
    return out, (z, dense_bias, scale, bias, mean, rstd)


def _layer_norm_relu_bwd(kernel: bool, residuals, grad):
    return (_backward_pallas if kernel else _backward_jnp)(grad, *residuals)


_layer_norm_relu.defvjp(_layer_norm_relu_fwd, _layer_norm_relu_bwd)
