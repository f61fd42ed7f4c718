"""The verdict on a bake: pass or fail by the spec's ``validate`` thresholds, with the
cause it can detect and what to change.

Judged at the shipped n on the held-out lights: the held-out error (pooled over the
lights, √(Σ‖rec − ref‖² / Σ‖ref‖²); with a path-traced reference, the mean
noise-corrected error per light) against ``validate.target_ratio`` × the projection
bound (pooled alike; with a path-traced reference, the basis projected on those
references, their noise removed: :class:`prtcore.validate.BasisAtTexels`) (the best any
transfer could do with this basis), and the held-out error relative to the RMS of all
held-out indirect lightmaps against ``validate.max_error``. A failing bake still writes
its bundle; ``prtcore bake`` then exits with :data:`EXIT_POOR` unless ``--allow-poor``.
"""

from __future__ import annotations

from typing import Any

#: exit status of ``prtcore bake`` when the verdict fails (the bundle is written)
EXIT_POOR = 3


def _row(table: dict, n: int) -> dict | None:
    return next((r for r in table.get("rows", []) if r["n"] == n), None)


def judge(table: dict, diagnostics: dict, n: int, validate, *, points: int,
          configurations: int, black_channels: tuple[str, ...] = (),
          reference: dict | None = None) -> dict[str, Any]:
    """The verdict as JSON data.

    table : report.error_vs_runtime output; diagnostics : the fit's diagnostics dict;
    n : the shipped element count; validate : the spec's ValidateSpec; points, configurations:
    P and K; black_channels : channel names ("R", "G", "B") with zero albedo everywhere;
    reference : optional path-traced validation (validate.validate_bundle output): its
    noise-corrected error at n replaces the fast transport's.
    Returns {"status": "pass" | "fail" | "unknown", "n", "error", "bound", "ratio",
    "error_global", "target_ratio", "max_error", "against", "causes": [{"cause",
    "advice"}], "line"}.
    """
    row = _row(table, n)
    out: dict[str, Any] = {"n": n, "target_ratio": validate.target_ratio,
                           "max_error": validate.max_error, "causes": []}
    if row is None or row.get("heldout_rmse_mean") is None:
        held = table.get("heldout_configurations", 0)
        why = ("no held-out lights (set lights.holdout > 0)" if not held else
               f"none of the {held} held-out lights gives direct and indirect light at the "
               "measurement points (a light family the asset does not see?)")
        out.update(status="unknown", error=None, bound=None, ratio=None, error_global=None,
                   against=None, line=f"verdict: unknown — {why}")
        return out
    # pooled over the held-out lights (each weighs the indirect light it holds: a light
    # with almost none cannot fail the gate alone); the per-light mean where not reported
    error = row.get("heldout_rmse_pooled", row["heldout_rmse_mean"])
    bound = row.get("projection_bound_pooled", row.get("projection_bound_mean"))
    against = table.get("reference") or "fast transport"
    if reference is not None:
        rr = _row(reference, n)
        if rr is not None and rr.get("rmse_noise_corrected_mean") is not None:
            error = rr["rmse_noise_corrected_mean"]
            # the basis projected on the path-traced references themselves (noise removed),
            # the same lights as the error; the fast transport's where it cannot be
            bound = rr.get("projection_bound_noise_corrected_mean") or row.get(
                "projection_bound_mean")
            against = f"{reference['reference']}, noise removed"
    ratio = error / bound if bound else (1.0 if error == 0 else float("inf"))
    error_global = row.get("heldout_rmse_global_mean")
    out.update(error=error, bound=bound, ratio=ratio, error_global=error_global,
               against=against)

    causes = []
    too_far = ratio > validate.target_ratio
    too_big = error_global is not None and error_global > validate.max_error
    if black_channels:
        causes.append({"cause": f"black channel: albedo {'/'.join(black_channels)} is zero "
                                "everywhere, so those channels carry no light",
                       "advice": "check the materials' baseColor; fit.channels = rgb keeps "
                                 "the other channels' basis clean"})
    if too_far:
        rank = min(diagnostics.get("direct_effective_rank") or [0])
        excluded = len(diagnostics.get("excluded") or [])
        if excluded > configurations // 4:
            causes.append({"cause": f"{excluded} of {configurations} training lights give no "
                                    "direct light at the measurement points",
                           "advice": "the light family does not fit the asset: move the "
                                     "family where the asset is, or place points where the "
                                     "lights reach (measurement_points.placement)"})
        if points > configurations - 1:
            causes.append({"cause": f"more measurement points ({points}) than training "
                                    f"lights ({configurations}): the transfer is "
                                    "underdetermined",
                           "advice": f"more lights (lights.count ≥ {4 * points})"})
        if rank < min(points, configurations - 1) // 2:
            causes.append({"cause": f"the measurement points see the lights in only {rank} "
                                    "independent ways",
                           "advice": "more measurement points, spread where the lights "
                                     "reach; or a light family the points can see"})
        if not any(c["cause"].startswith(("more measurement", "the measurement",
                                          f"{excluded} of")) for c in causes):
            causes.append({"cause": f"the transfer predicts the basis coefficients "
                                    f"{ratio:.2f}× worse than the basis allows",
                           "advice": f"more measurement points (measurement_points.count > "
                                     f"{points}) and more lights (lights.count > "
                                     f"{configurations})"})
    if too_big and not too_far:
        causes.append({"cause": f"the basis of {n} elements cannot represent the held-out "
                                f"lighting (projection bound {100 * (bound or 0):.1f} %)",
                       "advice": f"a higher fit.basis than {n}, or more lights so the basis "
                                 "sees more of the family"})
    status = "fail" if (too_far or too_big) else "pass"
    out.update(status=status, causes=causes)
    head = (f"verdict: {status} — held-out error {100 * error:.1f} % at n = {n} "
            f"({against}), {ratio:.2f}× the projection bound (limit "
            f"{validate.target_ratio:g}×)")
    if error_global is not None:
        head += (f", {100 * error_global:.1f} % of the held-out RMS (limit "
                 f"{100 * validate.max_error:g} %)")
    if status == "fail" and causes:
        head += "; " + "; ".join(f"{c['cause']} → {c['advice']}" for c in causes)
    out["line"] = head
    return out
