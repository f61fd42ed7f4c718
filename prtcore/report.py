"""Error against run time: the table every bake reports (paper section 5).

For n ∈ {4, 8, 16, 32, 64} (≤ what the fit allows): relative RMSE of the held-out
configurations against their reference, the projection bound (the reference projected
onto the basis: the best any transfer could do with n elements), the CPU cost of the
coefficients (u = M·x, plus the learnt residual of an "mlp" transfer; µs) and of the
basis blend at atlas size (ms), and storage.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from prtcore.core.mlp import transfer_residual, transfer_rows
from prtcore.core.progress import StageTimer
from prtcore.fit.model import TransferModel
from prtcore.fit.transfer import fit_transfer, heldout_errors

TABLE_N = (4, 8, 16, 32, 64)
#: The CPU blend timing runs on at most this many pixels (512²; 64 elements are then 68 MB,
#: far beyond the caches, so the product is as memory-bound as at atlas size) and is scaled
#: linearly to the atlas.
BLEND_TIMING_PIXELS = 1 << 18
#: Runs of the blend timing per basis size (the median is reported): 3, not more — each
#: run streams up to 68 MB, and the report stage is held to about a second (issue 20).
BLEND_TIMING_REPEATS = 3


def fit_for_table(D: np.ndarray, I: np.ndarray, fit_spec, holdout=None,
                  timer: StageTimer | None = None, **kw) -> tuple[TransferModel, TransferModel]:
    """The fit a data-driven bake ships and the one its table uses, from the spec's ``fit``
    section: (model, full), ``full`` with ≥ max(TABLE_N) elements where the data allows,
    ``model`` its first n (fit.basis) or the "auto" choice on ``holdout``.

    D : (P, K, 3), I : (T, K, 3) (denoised as the bake fits them); holdout : as
    :func:`~prtcore.fit.transfer.fit_transfer`; kw : groups, per_group (keyframes).
    One function for the method's fit and automatic sizing's trials (prtcore/sizing.py),
    so a trial's figures are the shipped bake's.
    """
    from prtcore.fit.mlp import learnt_options

    n_table = max(TABLE_N)
    fit_kw = {"ridge": fit_spec.ridge, "channels": fit_spec.channels,
              "gamma": fit_spec.gamma, "timer": timer,  # progress bars
              "transfer": fit_spec.transfer, "transfer_options": learnt_options(fit_spec),
              **kw}
    if fit_spec.basis == "auto":
        model = fit_transfer(D, I, basis="auto", holdout=holdout, **fit_kw)
        full = model if model.n_basis >= n_table else fit_transfer(
            D, I, basis=n_table, **fit_kw)
    else:
        full = fit_transfer(D, I, basis=max(fit_spec.basis, n_table), **fit_kw)
        model = truncate(full, fit_spec.basis)
    return model, full


def truncate(model: TransferModel, n: int) -> TransferModel:
    """The model with its first n elements (mean included). Exact: rows of the transfer
    are independent regressions, so the n-element fit is a prefix of the larger one."""
    import dataclasses

    nb = max(0, n - 1)
    diag = model.diagnostics
    if n < model.n_basis:  # the diagnostics describe the truncated model, not the larger fit
        diag = dataclasses.replace(
            diag, n_basis=nb + 1, n_basis_requested=n, n_basis_method="given",
            energy_kept=diag.energy_curve[nb],
            warnings=tuple(w for w in diag.warnings if not w.startswith("basis count ")))
    elif diag.n_basis_requested != n:  # the larger fit was capped below n: say n, not its size
        capped = model.n_basis < n
        diag = dataclasses.replace(
            diag, n_basis_requested=n,
            n_basis_method="capped" if capped else diag.n_basis_method,
            warnings=tuple(
                w for w in diag.warnings if not w.startswith("basis count ")) + (
                (f"basis count {n} capped at {model.n_basis}: the indirect data has rank "
                 f"{diag.indirect_rank} after mean subtraction",) if capped else ()))
    learnt = None if model.learnt is None else model.learnt.select_outputs(
        transfer_rows(model.basis.shape[1], min(nb, model.basis.shape[1])))
    return dataclasses.replace(model, basis=model.basis[:, :nb], transfer=model.transfer[
        ..., :nb, :], offset=model.offset[..., :nb], diagnostics=diag, learnt=learnt)


def _time(fn, repeat: int) -> float:
    """Median seconds of ``fn()`` over ``repeat`` runs."""
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def heldout_metrics(model: TransferModel, holdout_direct: np.ndarray,
                    holdout_indirect: np.ndarray, ns: list[int],
                    groups: np.ndarray | None = None) -> list[dict[str, float | None]]:
    """The accuracy columns of the table for each n of ``ns`` (the verdict's inputs; also
    what automatic sizing judges a (P, K) by, prtcore/sizing.py).

    holdout_direct : (P, H, 3), holdout_indirect : (T, H, 3); groups : (H,) keyframe of
    each held-out configuration (per-keyframe transfers only). Configurations without
    direct light at the points are left out; those without indirect light count only in
    the global and absolute errors. Per n: the per-light relative RMSE (mean, max) and
    projection bound (mean, max), both pooled over the lights (√(Σ‖rec − ref‖² / Σ‖ref‖²),
    each light weighing the indirect light it holds), the error relative to the RMS of
    *all* held-out lightmaps (mean, max), the absolute RMSE (radiance units) and the
    fraction of texels reconstructed negative.
    """
    H = holdout_direct.shape[1]
    T = holdout_indirect.shape[0]
    lit = np.array([np.linalg.norm(holdout_direct[:, h, :]) > 0 for h in range(H)], bool)
    # every size's reconstructions and projections in one pass over the texels
    # (fit/transfer.py heldout_errors), not one pass per light and size
    use = np.flatnonzero(lit)
    err = heldout_errors(model, holdout_direct[:, use], holdout_indirect[:, use], ns,
                         None if groups is None else np.asarray(groups)[use])
    # the honest scale: the RMS of the held-out indirect over *all* held-out
    # configurations, so a light with almost no indirect light does not read as 14 000 %
    ref_ss = np.zeros(H)
    ref_ss[use] = err.ref_ss
    ref_ss[~lit] = [float(np.sum(holdout_indirect[:, h, :].astype(np.float64) ** 2))
                    for h in np.flatnonzero(~lit)]
    global_norm = float(np.sqrt(np.mean(ref_ss))) if H else 0.0
    has_ref = err.ref_ss > 0
    out = []
    for i in range(len(ns)):
        diff = np.sqrt(err.sse[i])
        errs = diff[has_ref] / np.sqrt(err.ref_ss[has_ref])
        bounds = np.sqrt(err.bound_sse[i][has_ref] / err.ref_ss[has_ref])
        errs_global = diff / global_norm if global_norm > 0 else np.zeros(0)
        abs_rmse = diff / np.sqrt(3 * T)
        negative = err.negative[i]
        # pooled: Σ‖rec − ref‖², Σ (bound·‖ref‖)², Σ‖ref‖²
        pooled = (float(err.sse[i][has_ref].sum()), float(err.bound_sse[i][has_ref].sum()),
                  float(err.ref_ss[has_ref].sum()))
        out.append({
            "heldout_rmse_mean": float(np.mean(errs)) if errs.size else None,
            "heldout_rmse_max": float(np.max(errs)) if errs.size else None,
            "projection_bound_mean": float(np.mean(bounds)) if bounds.size else None,
            "projection_bound_max": float(np.max(bounds)) if bounds.size else None,
            # pooled over the held-out lights: √(Σ‖rec − ref‖² / Σ‖ref‖²) and the same for
            # the projection; a light with almost no indirect light weighs what it holds
            "heldout_rmse_pooled": float(np.sqrt(pooled[0] / pooled[2])) if pooled[2] else None,
            "projection_bound_pooled": float(np.sqrt(pooled[1] / pooled[2]))
            if pooled[2] else None,
            # per configuration ‖rec − ref‖ / RMS of all held-out indirect lightmaps
            "heldout_rmse_global_mean": float(np.mean(errs_global)) if errs_global.size
            else None,
            "heldout_rmse_global_max": float(np.max(errs_global)) if errs_global.size
            else None,
            # radiance units (linear RGB, per texel and channel)
            "heldout_abs_rmse_mean": float(np.mean(abs_rmse)) if abs_rmse.size else None,
            "negative_texel_fraction": float(np.mean(negative)) if negative.size else None,
        })
    return out


def error_vs_runtime(model: TransferModel, holdout_direct: np.ndarray,
                     holdout_indirect: np.ndarray, atlas_pixels: int,
                     planes_bytes_per_element: float, reference: str,
                     groups: np.ndarray | None = None, shipped: int | None = None) -> dict:
    """The table.

    holdout_direct : (P, H, 3), holdout_indirect : (T, H, 3) reference indirect radiance.
    atlas_pixels : W·H (the blend runs over the whole atlas, as in a fragment shader).
    groups : (H,) keyframe of each held-out configuration (per-keyframe transfers only).
    shipped : the n that ships, given a row too (≤ model.n_basis; the verdict's row)
    """
    ns = [n for n in TABLE_N if n <= model.n_basis]
    for extra in (model.n_basis, shipped):
        if extra is not None and extra not in ns:
            ns.append(extra)
    ns = sorted(ns)
    H = holdout_direct.shape[1]
    rows = []
    rng = np.random.default_rng(0)
    # configurations without direct light at the measurement points (or without indirect
    # light) have no relative error: skipped, and listed so that the skip is visible
    skipped = []
    for h in range(H):
        if not np.linalg.norm(holdout_direct[:, h, :]) > 0:
            skipped.append({"index": h, "reason": "zero direct"})
        elif not np.linalg.norm(holdout_indirect[:, h, :]) > 0:
            skipped.append({"index": h, "reason": "zero indirect"})
    accuracy = heldout_metrics(model, holdout_direct, holdout_indirect, ns, groups)
    # the blend timing's image, allocated once at the largest size (a product's speed does
    # not depend on the values)
    px = min(atlas_pixels, BLEND_TIMING_PIXELS)
    planes_max = 3 + (max(ns) - 1) * (1 if model.channels == "mono" else 3)
    img_all = np.full(px * planes_max, 0.5, dtype=np.float32)
    for i, n in enumerate(ns):
        M = model.transfer[..., : n - 1, :]
        M = M if M.ndim == 3 else M[0]
        x32 = rng.random((M.shape[-1],)).astype(np.float32)
        net = None if model.learnt is None else model.learnt.select_outputs(
            transfer_rows(model.basis.shape[1], n - 1))
        if net is None:
            u_s = _time(lambda M=M, x32=x32: [M[c] @ x32 for c in range(3)], 200)
        else:  # the learnt residual is part of the coefficients' cost
            x3 = np.random.default_rng(1).random((M.shape[-1], 3))
            u_s = _time(lambda M=M, x32=x32, net=net, x3=x3: (
                [M[c] @ x32 for c in range(3)], transfer_residual(net, x3)), 200)
        planes = 3 + (n - 1) * (1 if model.channels == "mono" else 3)
        # timed on at most BLEND_TIMING_PIXELS pixels and scaled to the atlas (linear in
        # pixels): a 4096² atlas of 64 elements would otherwise allocate 9 GB here
        img = img_all[:px * planes].reshape(px, planes)
        w = rng.random((planes, 3)).astype(np.float32)
        blend_s = _time(lambda img=img, w=w: img @ w, BLEND_TIMING_REPEATS) * (atlas_pixels / px)
        files = -(-planes // 4)
        storage = int(files * 4 * planes_bytes_per_element + M.size * 4 * (
            1 if model.transfer.ndim == 3 else model.transfer.shape[0]))
        if net is not None:
            storage += 4 * sum(w.size + c.size for w, c in zip(net.weights, net.biases,
                                                               strict=True))
        rows.append({
            "n": n,
            **accuracy[i],
            "cpu_coefficients_us": u_s * 1e6,
            "cpu_blend_ms": blend_s * 1e3,
            "textures": files,
            "storage_bytes": storage,
        })
    return {"reference": reference, "heldout_configurations": H, "heldout_skipped": skipped,
            "rows": rows}


def format_skipped(skipped: list[dict]) -> str:
    """The held-out configurations the table skips, in the words of ``report.json``
    (``heldout_skipped[].reason``): "8 skipped: zero indirect", or per reason when they
    differ, "3 skipped: 2 zero direct, 1 zero indirect". Empty when none are skipped."""
    if not skipped:
        return ""
    counts: dict[str, int] = {}
    for s in skipped:
        counts[s["reason"]] = counts.get(s["reason"], 0) + 1
    if len(counts) == 1:
        return f"{len(skipped)} skipped: {next(iter(counts))}"
    return f"{len(skipped)} skipped: " + ", ".join(f"{c} {r}" for r, c in counts.items())


def format_table(table: dict, seconds: dict[str, float] | None = None) -> str:
    skipped = format_skipped(table.get("heldout_skipped") or [])
    lines = [f"error against run time — held-out configurations: "
             f"{table['heldout_configurations']}"
             + (f" ({skipped})" if skipped else "")
             + f", reference: {table['reference']}",
             f"{'n':>4s} {'held-out rRMSE':>15s} {'(max)':>8s} {'proj. bound':>12s} "
             f"{'u=M·x µs':>10s} {'blend ms':>9s} {'EXRs':>5s} {'storage':>10s}"]
    for r in table["rows"]:
        def pct(v):
            return "—" if v is None else f"{100 * v:.2f}%"
        lines.append(f"{r['n']:>4d} {pct(r['heldout_rmse_mean']):>15s} "
                     f"{pct(r['heldout_rmse_max']):>8s} {pct(r['projection_bound_mean']):>12s} "
                     f"{r['cpu_coefficients_us']:>10.1f} {r['cpu_blend_ms']:>9.2f} "
                     f"{r['textures']:>5d} {r['storage_bytes'] / 2**20:>8.2f} MiB")
    lines += _gpu_lines(table)
    if seconds:
        lines.append("bake stages: " + ", ".join(f"{k} {v:.2f} s" for k, v in seconds.items())
                     + f"; total {sum(seconds.values()):.2f} s")
    return "\n".join(lines)


#: Optional per-row GPU fields: (key in the gpu table, column title). Each is stored twice
#: in a row, ``gpu_<key>_ms`` (GL timer query) and ``gpu_<key>_wall_ms`` (wall clock
#: between glFinish calls).
GPU_FIELDS = (("points", "points"), ("coefficients", "u=M·x"), ("atlas_blend", "blend"))


def merge_gpu_columns(table: dict, gpu: dict) -> dict:
    """Add GPU columns to the table in place (and return it).

    gpu : :func:`prtcore.runtime.gl.gpu_runtime_table` output (milliseconds). Rows of the
    table whose n was measured get ``gpu_points_ms``, ``gpu_coefficients_ms``,
    ``gpu_atlas_blend_ms`` (the blend over the whole atlas) from GL timer queries and the
    same names with ``_wall_ms`` from the wall clock; ``table["gpu_renderer"]`` names the
    GL renderer ("… (software)" for Mesa's CPU rasterisers, so that those figures are not
    read as GPU timings).
    """
    by_n = {int(r["n"]): r for r in gpu["rows"]}
    for row in table["rows"]:
        g = by_n.get(int(row["n"]))
        if g is not None:
            for key, _ in GPU_FIELDS:
                row[f"gpu_{key}_ms"] = g.get(key)
                row[f"gpu_{key}_wall_ms"] = g.get("wall", {}).get(key)
    table["gpu_renderer"] = gpu["renderer"]
    return table


def _gpu_lines(table: dict) -> list[str]:
    """The GPU columns as a second block (only when measured): "query / wall" ms."""
    rows = [r for r in table["rows"] if any(f"gpu_{k}_wall_ms" in r for k, _ in GPU_FIELDS)]
    if not rows:
        return []

    def ms(v):
        return "—" if v is None else f"{v:.3f}"

    lines = [f"runtime ms (GL timer query / wall clock with glFinish) on "
             f"{table.get('gpu_renderer', 'unknown renderer')}",
             f"{'n':>4s} " + " ".join(f"{title:>19s}" for _, title in GPU_FIELDS)]
    for r in rows:
        cells = [f"{ms(r.get(f'gpu_{k}_ms'))} / {ms(r.get(f'gpu_{k}_wall_ms'))}"
                 for k, _ in GPU_FIELDS]
        lines.append(f"{r['n']:>4d} " + " ".join(f"{c:>19s}" for c in cells))
    return lines


def preload_plotting() -> threading.Thread:
    """Import matplotlib's ``Figure`` and Agg canvas on a daemon thread, so that a bake pays
    the import (about half a second) while its transport runs rather than in its report
    and export stages. Returns the thread (joining it is optional)."""
    def load() -> None:
        import matplotlib.backends.backend_agg
        import matplotlib.figure  # noqa: F401

    thread = threading.Thread(target=load, name="preload-matplotlib", daemon=True)
    thread.start()
    return thread


def _figure(size: tuple[float, float], columns: int = 1):
    """A matplotlib figure of ``size`` inches at 100 dpi and its axes (one, or a row of
    ``columns``), made without pyplot: no global figure state, and no pyplot import (about
    a second of every bake's export)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=100)
    return fig, fig.subplots(1, columns)


def plot(table: dict, path: Path, verdict: dict | None = None) -> None:
    """report.png: held-out error and projection bound against n, with CPU cost; with a
    verdict, the shipped n is marked and the gate (target ratio × bound) drawn."""
    rows = [r for r in table["rows"] if r["heldout_rmse_mean"] is not None]
    fig, ax = _figure((6, 4))
    if rows:
        n = [r["n"] for r in rows]
        ax.plot(n, [100 * r["heldout_rmse_mean"] for r in rows], "o-", label="held-out rRMSE")
        ax.plot(n, [100 * r["projection_bound_mean"] for r in rows], "s--",
                label="projection bound")
        if verdict and verdict.get("target_ratio"):
            k = verdict["target_ratio"]
            ax.plot(n, [100 * k * r["projection_bound_mean"] for r in rows], ":",
                    color="tab:red", label=f"gate: {k:g}× bound")
        if verdict and verdict.get("error") is not None:
            ax.plot([verdict["n"]], [100 * verdict["error"]], "*", ms=14,
                    color="tab:green" if verdict["status"] == "pass" else "tab:red",
                    label=f"shipped n = {verdict['n']} ({verdict['status']})")
        ax.set_xscale("log", base=2)
        ax.set_xticks(n, [str(v) for v in n])
        ax2 = ax.twinx()
        ax2.plot(n, [r["cpu_blend_ms"] for r in rows], "^:", color="grey",
                 label="CPU blend (ms)")
        ax2.set_ylabel("CPU blend at atlas size (ms)")
    ax.set_xlabel("basis elements n (mean included)")
    ax.set_ylabel("relative RMSE (%)")
    ax.set_title(f"error against run time ({table['heldout_configurations']} held-out)")
    # one legend for both axes, and none without labelled lines (no rows with an error):
    # legend() without labelled artists warns "No artists with labels found" on stderr
    handles, labels = [], []
    for a in fig.axes:
        h, lb = a.get_legend_handles_labels()
        handles += h
        labels += lb
    if handles:
        ax.legend(handles, labels, loc="upper right")
    fig.tight_layout()
    fig.savefig(path)


def plot_worst(ref: np.ndarray, rec: np.ndarray, title: str, path: Path) -> None:
    """report_worst.png: the worst held-out light's reference, reconstruction and signed
    error, as atlas images (h, w, 3) linear RGB; coverage-less texels are black."""
    lum = np.array([0.2126, 0.7152, 0.0722])
    scale = float(np.percentile(ref @ lum, 99)) or 1.0
    err = (rec - ref) @ lum
    lim = float(np.max(np.abs(err))) or 1.0
    fig, axes = _figure((10, 3.6), 3)
    for ax, img, name in ((axes[0], ref, "reference"), (axes[1], rec, "reconstruction")):
        ax.imshow(np.clip(img / scale, 0, 1) ** (1 / 2.2), interpolation="nearest")
        ax.set_title(name)
    im = axes[2].imshow(err, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
    axes[2].set_title("signed error (luminance)")
    fig.colorbar(im, ax=axes[2], fraction=0.046)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)


def plot_atlas(density: np.ndarray, utilisation: float, title: str, path: Path) -> None:
    """report_atlas.png: the UV layout coloured by texel density (texels per metre; 0 where
    no geometry) and the atlas utilisation."""
    fig, ax = _figure((5.5, 5))
    shown = np.where(density > 0, density, np.nan)
    im = ax.imshow(shown, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, fraction=0.046, label="texels per metre")
    ax.set_title(f"{title}\nutilisation {100 * utilisation:.1f} % of the atlas")
    ax.set_xticks([])
    ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path)
