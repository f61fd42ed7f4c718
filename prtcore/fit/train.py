"""Training the networks of :mod:`prtcore.core.mlp` (the learnt transfer of
:mod:`prtcore.fit.mlp`, the learnt SH transfer of :mod:`prtcore.fit.learnt_sh`).

JAX with optax on the CPU: wheels without GPU payloads, ``jax.enable_x64`` for float64
fitting, explicit PRNG keys. AdamW, full batch or seeded minibatches; deterministic: the
same data, options and seed give the same weights bit for bit on one machine. Inputs are
centred and scaled (one scale for all features) and, for a linear output, the targets
scaled; both are folded into the first and last layer, so the returned network reads the
raw inputs and writes the raw targets. The last layer starts at zero (the network starts
at 0: for a residual, exactly the model it corrects). Loss and ETA are shown on the
stage's progress bar (:func:`prtcore.core.progress.bar`).
"""

from __future__ import annotations

import itertools

import numpy as np

from prtcore.core.mlp import LEAKY_SLOPE, Mlp
from prtcore.core.progress import bar

#: AdamW learning rate and decoupled weight decay
LEARNING_RATE = 1e-3
WEIGHT_DECAY = 1e-4
#: the validation error is read (and the bar updated) every this many steps
CHECK_EVERY = 10


def train_network(X: np.ndarray, Y: np.ndarray, widths: tuple[int, ...], steps: int,
                  seed: int, *, val: tuple[np.ndarray, np.ndarray] | None = None,
                  desc: str = "training", output: str = "linear", batch: int | None = None,
                  learning_rate: float = LEARNING_RATE) -> tuple[Mlp, np.ndarray]:
    """AdamW on the mean squared error of ``net(X) ≈ Y`` for ``steps`` steps.

    X : (N, d_in) float64; Y : (N, d_out) float64 (within (−1, 1) for ``output="tanh"``:
    those targets are not scaled); widths : hidden layer sizes (leaky ReLU);
    val : (X_v, Y_v) validation set, read every CHECK_EVERY steps; batch : minibatch
    size (None: full batch), drawn from a generator seeded by ``seed``.
    Returns the network (float64) and the validation curve (checks, 2) float64 of
    (step, mean squared error in Y's units), step 0 first (empty without ``val``).
    """
    import jax
    import jax.numpy as jnp
    import optax

    n_rows = len(X)
    full = batch is None or batch >= n_rows
    with jax.enable_x64(True):
        mu = X.mean(axis=0)
        sigma = float(np.sqrt(np.mean((X - mu) ** 2))) or 1.0
        tau = 1.0 if output == "tanh" else (float(np.sqrt(np.mean(Y**2))) or 1.0)
        xs, ys = jnp.asarray((X - mu) / sigma), jnp.asarray(Y / tau)
        sizes = (X.shape[1], *widths, Y.shape[1])
        keys = jax.random.split(jax.random.PRNGKey(seed), len(sizes) - 1)
        params = []
        for j, (n_in, n_out) in enumerate(itertools.pairwise(sizes)):
            last = j == len(sizes) - 2
            w = jnp.zeros((n_out, n_in)) if last else \
                jax.random.normal(keys[j], (n_out, n_in), jnp.float64) * np.sqrt(2.0 / n_in)
            params.append((w, jnp.zeros(n_out)))

        def apply(p, x):
            h = x
            for j, (w, c) in enumerate(p):
                h = h @ w.T + c
                if j < len(p) - 1:
                    h = jnp.where(h >= 0.0, h, LEAKY_SLOPE * h)
            return jnp.tanh(h) if output == "tanh" else h

        @jax.jit
        def loss(p, x, y):
            return jnp.mean((apply(p, x) - y) ** 2)

        opt = optax.adamw(learning_rate, weight_decay=WEIGHT_DECAY)

        @jax.jit
        def run(p, state, idx):
            def body(i, carry):
                p, state = carry
                if full:
                    g = jax.grad(loss)(p, xs, ys)
                else:
                    g = jax.grad(loss)(p, xs[idx[i]], ys[idx[i]])
                upd, state = opt.update(g, state, p)
                return optax.apply_updates(p, upd), state
            return jax.lax.fori_loop(0, idx.shape[0], body, (p, state))

        rng = np.random.default_rng(seed)
        state = opt.init(params)
        curve = []
        if val is not None:
            xv, yv = jnp.asarray((val[0] - mu) / sigma), jnp.asarray(val[1] / tau)
            curve.append((0, float(loss(params, xv, yv)) * tau**2))
        done = 0
        chunks = -(-steps // CHECK_EVERY)
        progress = bar(range(chunks), desc, total=chunks)
        for _ in progress:
            n = min(CHECK_EVERY, steps - done)
            idx = np.zeros((n, 1), np.int64) if full else \
                np.stack([rng.choice(n_rows, batch, replace=False) for _ in range(n)])
            params, state = run(params, state, jnp.asarray(idx))
            done += n
            if val is not None:
                curve.append((done, float(loss(params, xv, yv)) * tau**2))
            if not getattr(progress, "disable", True):  # a bar is drawn: loss on it
                shown = f"val {curve[-1][1]:.3g}" if val is not None else \
                    f"loss {float(loss(params, xs, ys)) * tau**2:.3g}"
                progress.set_postfix_str(shown, refresh=False)
        weights = [np.asarray(w, np.float64) for w, _ in params]
        biases = [np.asarray(c, np.float64) for _, c in params]
    # fold the standardisation: the first layer reads X, the last layer writes Y
    biases[0] = biases[0] - weights[0] @ mu / sigma
    weights[0] = weights[0] / sigma
    weights[-1], biases[-1] = weights[-1] * tau, biases[-1] * tau
    return Mlp(tuple(weights), tuple(biases), LEAKY_SLOPE, output), np.asarray(curve)
