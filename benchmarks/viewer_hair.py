"""Benchmark: the web viewer's hair drawing against the CPU renderer of hair bundles.

Bakes the tiny tangle of tests/test_viewer.py (200 strands, 4 texels per strand, 8 basis
elements), opens it in headless Chromium (SwiftShader) and renders one view in the page's
direct and indirect modes; the same view is rendered by prtcore/runtime/strands.py
(`prtcore render` of a hair bundle: fibre tubes ray traced, direct light at the tube's hit
point with ray-traced shadows, indirect from the relit strand texture). Lines and tubes do
not cover the same pixels (a one-pixel line against the tube's projected width, and the
front-most fibre may differ), so only aggregates over the pixels both cover are compared:
mean radiance per term and the fraction of directly lit pixels. Also the page's light pass
time. Prints them and writes benchmarks/results/viewer_hair.json.

Usage: python benchmarks/viewer_hair.py [--strands 200]
"""

from __future__ import annotations

import argparse
import base64
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "tests"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from browser import launch, wait_ready  # noqa: E402
from test_viewer import HAIR_LIGHT, HAIR_SPEC  # noqa: E402

from prtcore import pipeline  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.emitters.lightfile import light_from_dict  # noqa: E402
from prtcore.io.hair import write_hair  # noqa: E402
from prtcore.reference.camera import Camera  # noqa: E402
from prtcore.runtime.strands import render_strands  # noqa: E402
from prtcore.scenes.hair import tangle  # noqa: E402
from prtcore.viewer.server import ViewerServer  # noqa: E402


def page_images(bundle: Path, view: dict) -> tuple[dict, float]:
    """The page's direct and indirect images (h, w, 4) for HAIR_LIGHT and ``view``, and
    the light pass in ms."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = launch(pw)
        with ViewerServer(bundle, quiet=True).start() as server:
            page = browser.new_page(viewport={"width": 640, "height": 440})
            page.goto(server.url)
            wait_ready(page)
            page.evaluate("l => prt.setLight(l)", HAIR_LIGHT)
            ms = page.evaluate("prt.lightMs")
            page.evaluate("v => prt.setView(v)", view)
            w, h = page.evaluate("[document.getElementById('view').width, "
                                 "document.getElementById('view').height]")
            out = {m: np.frombuffer(base64.b64decode(page.evaluate("m => prt.image(m)", m)),
                                    "<f4").reshape(h, w, 4) for m in ("direct", "indirect")}
        browser.close()
    return out, ms


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=200)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        hair = tangle(args.strands)
        t0 = time.perf_counter()
        bundle = pipeline.bake(write_hair(d / "tangle.hair", hair), parse_spec(HAIR_SPEC),
                               d / "bundle", quiet=True)
        bake_s = time.perf_counter() - t0
        lo, hi = hair.points.min(axis=0), hair.points.max(axis=0)
        c = (lo + hi) / 2
        r = float(np.linalg.norm(hair.points - c, axis=1).max())
        view = {"position": (c + np.array([0.0, 0.0, 2.9 * r])).tolist(), "target": c.tolist(),
                "up": [0, 1, 0], "fov_y_deg": 40}
        page, ms = page_images(bundle, view)
        h, w = page["direct"].shape[:2]
        camera = Camera(np.asarray(view["position"]), c, np.array([0.0, 1.0, 0.0]), 40.0, w, h)
        cpu = {m: render_strands(bundle, [light_from_dict(HAIR_LIGHT)], camera, mode=m)
               for m in ("direct", "indirect")}
    both = (page["direct"][..., 3] > 0) & (cpu["direct"][..., 3] > 0)
    res = {"strands": args.strands, "bake_s": bake_s, "light_pass_ms": ms,
           "coverage_page": float((page["direct"][..., 3] > 0).mean()),
           "coverage_cpu": float((cpu["direct"][..., 3] > 0).mean()),
           "coverage_both": float(both.mean())}
    for m in ("direct", "indirect"):
        a, b = page[m][both, :3].astype(np.float64), cpu[m][both, :3].astype(np.float64)
        res[m] = {"mean_page": a.mean(), "mean_cpu": b.mean(),
                  "relative_difference_of_means": a.mean() / b.mean() - 1,
                  "lit_fraction_page": float((a.sum(axis=1) > 0).mean()),
                  "lit_fraction_cpu": float((b.sum(axis=1) > 0).mean())}
    print(json.dumps(res, indent=1))
    out = ROOT / "benchmarks" / "results" / "viewer_hair.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
