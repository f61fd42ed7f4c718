"""Small fully connected networks evaluated in numpy: the one forward pass that the learnt
transfer's fit, its CPU runtime and the tests share (the GLSL of
``prtcore/runtime/shaders/learnt.glsl`` is tested against :func:`forward`).

A network of L layers maps an input h_0 (in,) to

    h_j = φ(W_j h_{j−1} + c_j)        j = 1 .. L−1   (hidden, φ = leaky ReLU)
    y   = ψ(W_L h_{L−1} + c_L)                         (ψ = identity or tanh)

with φ(v) = v for v ≥ 0 and ``slope``·v below. Weights are stored row-major (out, in), as
the bundle's raw files and the GLSL read them.

The learnt transfer of the data-driven method (:mod:`prtcore.fit.mlp`) is such a network
from the unit direct vector x̂ = x'/s (3P,), laid out ``[c][p]`` (channel-major, as the
transfer matrix), to a coefficient residual r (3 n_b,) laid out ``[c][i]``; the runtime
adds ``s·r`` to ``u`` (:func:`transfer_residual`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: negative slope of the hidden layers' leaky ReLU (thesis Fig. 4.2 uses leaky ReLU)
LEAKY_SLOPE = 0.01
#: output activations :func:`forward` knows
OUTPUTS = ("linear", "tanh")


@dataclass(frozen=True, eq=False)
class Mlp:
    """A fully connected network (module docstring).

    weights : L arrays (out_j, in_j) float32 or float64; biases : L arrays (out_j,)
    slope : leaky-ReLU negative slope of the hidden layers; output : "linear" | "tanh"
    """

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    slope: float = LEAKY_SLOPE
    output: str = "linear"

    def __post_init__(self) -> None:
        if not self.weights or len(self.weights) != len(self.biases):
            raise ValueError(f"mlp: {len(self.weights)} weight matrices and "
                             f"{len(self.biases)} bias vectors (need as many, at least 1)")
        for j, (w, c) in enumerate(zip(self.weights, self.biases, strict=True)):
            if w.ndim != 2 or c.shape != (w.shape[0],):
                raise ValueError(f"mlp: layer {j} weight {w.shape} and bias {c.shape} do "
                                 "not fit (expected (out, in) and (out,))")
            if j and w.shape[1] != self.weights[j - 1].shape[0]:
                raise ValueError(f"mlp: layer {j} takes {w.shape[1]} inputs but layer "
                                 f"{j - 1} gives {self.weights[j - 1].shape[0]}")
        if self.output not in OUTPUTS:
            raise ValueError(f"mlp: output {self.output!r}: expected one of {OUTPUTS}")

    @property
    def inputs(self) -> int:
        return int(self.weights[0].shape[1])

    @property
    def outputs(self) -> int:
        return int(self.weights[-1].shape[0])

    @property
    def widths(self) -> tuple[int, ...]:
        """Neurons of each hidden layer."""
        return tuple(int(w.shape[0]) for w in self.weights[:-1])

    def astype(self, dtype) -> Mlp:
        return Mlp(tuple(np.asarray(w, dtype) for w in self.weights),
                   tuple(np.asarray(c, dtype) for c in self.biases), self.slope, self.output)

    def select_outputs(self, rows: np.ndarray) -> Mlp:
        """The same network keeping output rows ``rows`` (int indices) only."""
        rows = np.asarray(rows, dtype=np.intp)
        return Mlp((*self.weights[:-1], self.weights[-1][rows]),
                   (*self.biases[:-1], self.biases[-1][rows]), self.slope, self.output)


def forward(net: Mlp, x: np.ndarray) -> np.ndarray:
    """The network at inputs x (..., inputs): (..., outputs) float64."""
    h = np.asarray(x, dtype=np.float64)
    if h.shape[-1] != net.inputs:
        raise ValueError(f"mlp: input of {h.shape[-1]} values, the network takes "
                         f"{net.inputs}")
    last = len(net.weights) - 1
    for j, (w, c) in enumerate(zip(net.weights, net.biases, strict=True)):
        h = h @ np.asarray(w, np.float64).T + np.asarray(c, np.float64)
        if j < last:
            h = np.where(h >= 0.0, h, net.slope * h)
    return np.tanh(h) if net.output == "tanh" else h


def positional_encoding(v: np.ndarray, frequencies: int) -> np.ndarray:
    """(..., d) → (..., d·(1 + 2F)) float64: v, then sin(2^k π v) for k < F, then
    cos(2^k π v) for k < F (each block d wide, k ascending) — the encoding the learnt SH
    network reads its position and normal through (thesis 4.1.2)."""
    v = np.asarray(v, dtype=np.float64)
    if frequencies == 0:
        return v
    arg = v[..., None, :] * (np.pi * 2.0 ** np.arange(frequencies))[:, None]  # (..., F, d)
    shape = (*v.shape[:-1], frequencies * v.shape[-1])
    return np.concatenate([v, np.sin(arg).reshape(shape), np.cos(arg).reshape(shape)],
                          axis=-1)


def transfer_rows(n_b_all: int, n_b: int) -> np.ndarray:
    """Output rows ``[c][i]`` of a learnt transfer with n_b_all rows per channel that the
    first n_b elements use: (3 n_b,) intp."""
    return (np.arange(3)[:, None] * n_b_all + np.arange(n_b)[None, :]).ravel()


def transfer_residual(net: Mlp, x: np.ndarray) -> np.ndarray:
    """The learnt transfer's coefficients per unit direct light: r (3, n_b) float64 for a
    gamma-space direct vector x (P, 3); zero for x = 0. The runtime adds ``s·r`` with
    s = ‖x‖ (so the whole transfer stays positively homogeneous)."""
    x = np.asarray(x, dtype=np.float64)
    s = float(np.linalg.norm(x))
    if net.inputs != x.size:
        raise ValueError(f"learnt transfer: direct vector of {x.shape[0]} points, the "
                         f"network takes {net.inputs // 3}")
    if s == 0.0:
        return np.zeros((3, net.outputs // 3))
    return forward(net, (x / s).T.ravel()).reshape(3, -1)
