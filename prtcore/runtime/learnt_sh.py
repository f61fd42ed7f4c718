"""The learnt SH transfer on the GPU (thesis 4.1.4.1): the network of
:class:`prtcore.fit.learnt_sh.LearntSh` with every weight matrix cut into 4 × 4 blocks
read as ``mat4`` (zero-padded to multiples of 4), evaluated one point per invocation.
The thesis bakes the blocks into the shader source as constants; here they sit in a
storage buffer: with the k = 64 and k = 128 networks as constant arrays, llvmpipe's
compiler had not finished after 10 minutes. :func:`gpu_evaluate` is
:func:`prtcore.fit.learnt_sh.evaluate` on the GPU (``tests/test_learnt_sh_gl.py`` holds
them equal to 1e-4).
"""

from __future__ import annotations

import numpy as np

from prtcore.fit.learnt_sh import LearntSh
from prtcore.runtime.glcontext import check_gl, set_uniform
from prtcore.runtime.glsl import shader_source

#: invocations per work group (the shader's local_size_x)
GROUP = 64


def _blocks(w: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """W (out, in) and b (out,) zero-padded to multiples of 4: (out4, in4, 4, 4), (out4, 4)."""
    o4, i4 = -(-w.shape[0] // 4), -(-w.shape[1] // 4)
    wp = np.zeros((4 * o4, 4 * i4))
    wp[:w.shape[0], :w.shape[1]] = w
    bp = np.zeros(4 * o4)
    bp[:len(b)] = b
    return wp.reshape(o4, 4, i4, 4).transpose(0, 2, 1, 3), bp.reshape(o4, 4)


def packed(model: LearntSh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The network as the shader reads it: every layer's 4 × 4 blocks as column-major
    mat4 (blocks, 16) float32, its biases (vec4s, 4) float32, and per layer (input vec4s,
    output vec4s, first block, first bias) (L, 4) int32."""
    mats, vecs, table = [], [], []
    for w, b in zip(model.net.weights, model.net.biases, strict=True):
        wb, bb = _blocks(np.asarray(w, np.float64), np.asarray(b, np.float64))
        o4, i4 = wb.shape[:2]
        table.append((i4, o4, sum(len(m) for m in mats), sum(len(v) for v in vecs)))
        # GLSL mat4 is column-major: column c holds W[4o + r, 4q + c] for r = 0..3
        mats.append(wb.transpose(0, 1, 3, 2).reshape(o4 * i4, 16))
        vecs.append(bb)
    return (np.concatenate(mats).astype("<f4"), np.concatenate(vecs).astype("<f4"),
            np.asarray(table, "<i4"))


def shader(model: LearntSh) -> str:
    """The compute shader's source for ``model``'s sizes and encoding."""
    _, _, table = packed(model)
    return shader_source("learnt_sh_cs.glsl", IN4=int(table[0, 0]),
                         MAX4=int(max(table[:, 0].max(), table[:, 1].max())),
                         LAYERS=len(table), POSITION_FREQUENCIES=model.position_frequencies,
                         NORMAL_FREQUENCIES=model.normal_frequencies)


def gpu_evaluate(ctx, model: LearntSh, position: np.ndarray, normal: np.ndarray
                 ) -> np.ndarray:
    """σ at points (n, 3) with unit normals (n, 3) in the moderngl context ``ctx``:
    (n, L²) float64 (computed in float32)."""
    n = len(position)
    out4 = -(-model.net.outputs // 4)

    def vec4s(a):
        v = np.zeros((max(n, 1), 4), "<f4")
        v[:n, :3] = a
        return ctx.buffer(v.tobytes())

    cs = ctx.compute_shader(shader(model))
    mats, vecs, table = packed(model)
    bufs = [vec4s(position), vec4s(normal), ctx.buffer(reserve=max(n, 1) * out4 * 16),
            ctx.buffer(mats.tobytes()), ctx.buffer(vecs.tobytes()),
            ctx.buffer(table.tobytes())]
    try:
        for k, buf in enumerate(bufs):
            buf.bind_to_storage_buffer(k)
        set_uniform(cs, "n_points", n)
        set_uniform(cs, "centre", tuple(float(c) for c in model.centre))
        set_uniform(cs, "inv_radius", 1.0 / model.radius)
        set_uniform(cs, "out_scale", model.scale)
        set_uniform(cs, "slope", model.net.slope)
        set_uniform(cs, "tanh_output", int(model.net.output == "tanh"))
        cs.run(group_x=max(1, -(-n // GROUP)))
        ctx.memory_barrier()
        out = np.frombuffer(bufs[2].read(), "<f4").reshape(-1, 4 * out4)[:n]
        check_gl(ctx, "learnt SH")
        return out[:, :model.net.outputs].astype(np.float64)
    finally:
        for buf in bufs:
            buf.release()
        cs.release()
