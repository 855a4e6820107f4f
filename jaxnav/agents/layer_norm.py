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
over each block of rows forward (read ``z``, write the output) and one backward (read the
output's gradient and ``z``, write ``z``'s gradient and each block's column sums of the three
parameter gradients), where XLA's fusions of the same function read each activation several
times (with flax's LayerNorm, reductions took 44% of the GPU's kernel time:
``benchmarks/results/archive/profile_training_h100_RobotNav-v0_flax_norm.md``). On a backend
without Triton the kernels run in Pallas's interpreter (tests), and shapes they do not take
(``kernel_fits``) use the jnp form. ``pallas=False``: jnp, which XLA fuses as it can.

XLA cannot split a kernel's rows over devices. Given a ``mesh`` of several devices, the kernels
run on each device's rows (``shard_map``, the rows split over ``rows_axis``, a vmapped seed
axis over the vmap's ``spmd_axis_name``), and the parameter gradients are summed over the
devices; row counts the devices do not divide evenly take the jnp form.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

EPSILON = 1e-6  # flax.linen.LayerNorm's default
# widths the kernels take: a whole row is one block, Triton wants powers of two
KERNEL_WIDTHS = tuple(2**k for k in range(7, 12))  # 128 .. 2048
# (rows, GPU warps) of one kernel instance, by row width, forward and backward, chosen on one
# H100 at 16,384 rows from each kernel timed alone, then the 1024-512-256 preset trained with a
# few (1024 backward at 8x4, 8x8 and 16x16, larger blocks at 256 and 512, smaller forward ones:
# all within 1%). At 1024 the backward's 16-row blocks spill: 80 us a call with 8 rows x 4
# warps, 85 with 16 x 8, 178 with 16 x 4
# (``benchmarks/results/archive/layer_norm_blocks_h100_one_block_an_instance.md``). 128 and
# 2048 follow the pattern, unmeasured. A backward instance walks several blocks in turn at 256
# (2 of 32 rows, 8 warps), 512 (2 of 8 rows) and 1024 (4 of 4), so that fewer column sums are
# written and reduced: at 512 and 1024 the preset trained at 6.75M env steps/s against 6.59M
# (README, "Training-loop throughput"); the 256 entry, the one the kernel table ranks first
# at 256 (``benchmarks/results/layer_norm_blocks_h100.md``, ``--walks``), came with the PQN's
# unrolled minibatch loop. Timed alone the kernels vary by a tenth from run to run at these
# sizes.
FORWARD_BLOCKS: dict[int, tuple[int, int]] = dict.fromkeys(KERNEL_WIDTHS, (8, 4))
# backward: (rows, warps, blocks an instance walks)
BACKWARD_BLOCKS: dict[int, tuple[int, int, int]] = {
    128: (32, 4, 1),
    256: (32, 8, 2),
    512: (8, 4, 2),
    1024: (4, 4, 4),
    2048: (4, 4, 1),
}


def kernel_fits(rows: int, width: int) -> bool:
    """Whether the Pallas kernels take ``rows`` x ``width`` (else the jnp form runs)."""
    if width not in KERNEL_WIDTHS:
        return False
    rows_per_block, _, walk = BACKWARD_BLOCKS[width]
    block = max(FORWARD_BLOCKS[width][0], rows_per_block * walk)
    return rows > 0 and rows % block == 0


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
def _forward_kernel(z_ref, dense_bias_ref, scale_ref, bias_ref, out_ref, mean_ref, rstd_ref):
    out, mean, rstd = _forward_math(z_ref[...], dense_bias_ref[...], scale_ref[...], bias_ref[...])
    out_ref[...] = out.astype(out_ref.dtype)
    mean_ref[...] = mean
    rstd_ref[...] = rstd


def _backward_kernel(
    walk: int,
    grad_ref, z_ref, dense_bias_ref, scale_ref, bias_ref, mean_ref, rstd_ref, dz_ref, sums_ref,
):  # fmt: skip
    """One instance: ``walk`` blocks of rows in turn (unrolled), their column sums of the three
    parameter gradients added up in registers and written once to ``sums_ref`` (4 rows, the
    4th there for Triton's power-of-two blocks and not written): fewer partial sums to write
    and to reduce after."""
    block = z_ref.shape[0] // walk
    params = (dense_bias_ref[...], scale_ref[...], bias_ref[...])
    total = None
    for j in range(walk):
        rows = pl.ds(j * block, block)
        dz, per_row = _backward_math(
            grad_ref[rows, :], z_ref[rows, :], *params, mean_ref[rows], rstd_ref[rows]
        )
        dz_ref[rows, :] = dz.astype(dz_ref.dtype)
        sums = [jnp.sum(g, axis=0) for g in per_row]
        total = sums if total is None else [t + s for t, s in zip(total, sums, strict=True)]
    for i, t in enumerate(total):
        sums_ref[pl.ds(i, 1), :] = t[None, :]


def _rows_spec(block: int, width: int) -> pl.BlockSpec:
    return pl.BlockSpec((block, width), lambda i: (i, 0))


def _vector_spec(width: int) -> pl.BlockSpec:
    return pl.BlockSpec((width,), lambda i: (0,))


def _per_row_spec(block: int) -> pl.BlockSpec:
    return pl.BlockSpec((block,), lambda i: (i,))


def _call(kernel, block: tuple[int, int], out_shape, in_specs, out_specs, name: str):
    rows_per_block, warps = block
    interpret = jax.default_backend() != "gpu"
    if interpret:
        params = None
    else:
        from jax.experimental.pallas import triton as pl_triton

        params = pl_triton.CompilerParams(num_warps=warps, num_stages=1)
    return pl.pallas_call(
        kernel,
        out_shape=out_shape,
        grid=(out_shape[0].shape[0] // rows_per_block,),
        in_specs=in_specs,
        out_specs=out_specs,
        interpret=interpret,
        compiler_params=params,
        name=name,
    )


def _forward_pallas(z, dense_bias, scale, bias):
    rows, width = z.shape
    block = FORWARD_BLOCKS[width][0]
    per_row = jax.ShapeDtypeStruct((rows,), jnp.float32)
    return _call(
        _forward_kernel,
        FORWARD_BLOCKS[width],
        (jax.ShapeDtypeStruct(z.shape, z.dtype), per_row, per_row),
        [_rows_spec(block, width)] + [_vector_spec(width)] * 3,
        (_rows_spec(block, width), _per_row_spec(block), _per_row_spec(block)),
        "layer_norm_relu_forward",
    )(z, dense_bias, scale, bias)


def _backward_pallas(grad, z, dense_bias, scale, bias, mean, rstd):
    rows, width = z.shape
    rows_per_block, warps, walk = BACKWARD_BLOCKS[width]
    block = rows_per_block * walk  # an instance's rows
    blocks = rows // block
    dz, sums = _call(
        functools.partial(_backward_kernel, walk),
        (block, warps),
        (
            jax.ShapeDtypeStruct(z.shape, z.dtype),
            jax.ShapeDtypeStruct((blocks * 4, width), jnp.float32),
        ),
        [_rows_spec(block, width)] * 2 + [_vector_spec(width)] * 3 + [_per_row_spec(block)] * 2,
        (_rows_spec(block, width), _rows_spec(4, width)),
        "layer_norm_relu_backward",
    )(grad.astype(z.dtype), z, dense_bias, scale, bias, mean, rstd)
    # one reduction over all blocks for the three sums (three took 3x the launches)
    total = sums.reshape(blocks, 4, width)[:, :3].sum(0)
    return (dz, total[0], total[1], total[2])


# ----------------------------------------------------------------------------- custom_vjp
@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _layer_norm_relu(kernel: bool, z, dense_bias, scale, bias):
    return (_forward_pallas if kernel else _forward_jnp)(z, dense_bias, scale, bias)[0]


def _layer_norm_relu_fwd(kernel: bool, z, dense_bias, scale, bias):
    out, mean, rstd = (_forward_pallas if kernel else _forward_jnp)(z, dense_bias, scale, bias)
    return out, (z, dense_bias, scale, bias, mean, rstd)


def _layer_norm_relu_bwd(kernel: bool, residuals, grad):
    return (_backward_pallas if kernel else _backward_jnp)(grad, *residuals)


_layer_norm_relu.defvjp(_layer_norm_relu_fwd, _layer_norm_relu_bwd)
