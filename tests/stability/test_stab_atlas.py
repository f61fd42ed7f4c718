"""Atlas resolution from 16² to 4096² (issue 8): small atlases bake or are refused with the
reason; large ones are bounded by configured limits (IntakeLimits.max_atlas_resolution,
checked before loading, and max_bake_bytes, the estimated peak memory, checked once the
texel space is built and before transport allocates)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from stab_helpers import CORNELL, HERE, assert_bundle_finite, bake, spec_with

from prtcore.core.errors import LimitExceeded, SpecError
from prtcore.core.limits import IntakeLimits
from prtcore.core.spec import parse_spec
from prtcore.pipeline import run_intake
from prtcore.transport.dataset import estimate_bake_bytes

#: The memory model may overestimate the measured peak by at most this factor.
ESTIMATE_SLACK = 1.6


def test_16_atlas_bakes_without_padding_and_refuses_with_padding(tmp_path):
    m = assert_bundle_finite(bake(CORNELL, spec_with(atlas={"resolution": 16, "padding": 0}),
                                  tmp_path / "a"))
    assert m["atlas"]["width"] == 16 and m["atlas"]["covered_texels"] > 64
    with pytest.raises(SpecError, match=r"spec atlas\.resolution: \d+ UV charts do not fit "
                                        r"in a 16×16 atlas with padding 2"):
        bake(CORNELL, spec_with(atlas={"resolution": 16, "padding": 2}), tmp_path / "b")
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize(("resolution", "limits"), [
    (4096, IntakeLimits(max_atlas_resolution=2048)),
    (4096, IntakeLimits.from_env({"PRT_LIMIT_MAX_ATLAS_RESOLUTION": "1024"})),
    (8192, IntakeLimits()),
])
def test_atlas_resolution_limit_refuses_before_loading(tmp_path, resolution, limits):
    spec = spec_with(atlas={"resolution": resolution})
    with pytest.raises(SpecError, match=rf"atlas\.resolution: {resolution} exceeds the "
                                        rf"configured limit max_atlas_resolution="
                                        rf"{limits.max_atlas_resolution}"):
        bake(tmp_path / "does-not-exist.glb", spec, tmp_path / "b", limits=limits)


def test_bake_memory_limit_is_checked_before_transport(tmp_path):
    spec = spec_with(atlas={"resolution": 128})
    intake = run_intake(CORNELL, parse_spec(spec), quiet=True)
    need = estimate_bake_bytes(intake.texels.count, 30, 16)
    with pytest.raises(LimitExceeded, match=r"the bake would need about .* GiB \(\d+ covered "
                                            r"texels of a 128×128 atlas, 30 lighting "
                                            rf"configurations.*limit max_bake_bytes={need - 1}"):
        bake(CORNELL, spec, tmp_path / "a", limits=IntakeLimits(max_bake_bytes=need - 1))
    assert not (tmp_path / "a").exists()
    assert_bundle_finite(bake(CORNELL, spec, tmp_path / "b",
                              limits=IntakeLimits(max_bake_bytes=need)))


def _bake_in_child(tmp_path, spec: dict) -> dict:
    """Bake in a fresh process; returns {"peak": bytes, "error": str|None}. The peak is the
    child's VmHWM: getrusage's ru_maxrss would carry this pytest process's size over the
    child's execve (Linux), measuring the parent when it is the larger."""
    code = f"""
import json, re, sys
sys.path[:0] = [{str(HERE)!r}, {str(HERE.parent)!r}]  # stab_helpers, and the tests/ it imports
from stab_helpers import CORNELL, bake
from prtcore.core.errors import PrtError
out = {{"error": None}}
try:
    bake(CORNELL, {spec!r}, __import__("pathlib").Path({str(tmp_path / "b")!r}))
except PrtError as e:
    out["error"] = type(e).__name__ + ": " + str(e)
hwm = re.search(r"VmHWM:\\s+(\\d+) kB", open("/proc/self/status").read())
out["peak"] = int(hwm.group(1)) * 1024
print(json.dumps(out))
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_memory_estimate_is_an_upper_bound_of_the_measured_peak(tmp_path):
    spec = spec_with(atlas={"resolution": 512, "padding": 4},
                     transport={"gather_rays": 8, "max_bounces": 4})
    out = _bake_in_child(tmp_path, spec)
    assert out["error"] is None, out
    t = json.loads((tmp_path / "b" / "manifest.json").read_text())["atlas"]["covered_texels"]
    est = estimate_bake_bytes(t, 30, 8, coarse=True)  # 512²: the solve's coarse grid
    print(f"peak {out['peak'] / 2**20:.0f} MiB, estimate {est / 2**20:.0f} MiB")
    assert out["peak"] <= est <= ESTIMATE_SLACK * out["peak"], (out["peak"], est)


@pytest.mark.slow
def test_4096_atlas_is_refused_by_the_default_memory_limit(tmp_path):
    """The Cornell box at 4096² (≈ 11 M covered texels) would need ≈ 30 GiB: refused after
    the texel space is built, with the peak memory staying far below the limit."""
    out = _bake_in_child(tmp_path, spec_with(atlas={"resolution": 4096, "padding": 4}))
    assert out["error"] is not None and out["error"].startswith("LimitExceeded: "), out
    assert "4096×4096 atlas" in out["error"] and "max_bake_bytes=" in out["error"]
    assert out["peak"] < IntakeLimits().max_bake_bytes / 2, out


@pytest.mark.slow
def test_1024_atlas_bakes_finite(tmp_path):
    spec = spec_with(atlas={"resolution": 1024, "padding": 4},
                     transport={"gather_rays": 4, "max_bounces": 4})
    m = assert_bundle_finite(bake(CORNELL, spec, tmp_path / "b"))
    assert m["atlas"]["covered_texels"] > 500_000


def test_report_timing_memory_does_not_grow_with_the_atlas():
    """The report times the CPU blend "over the whole atlas". Before the fix it allocated
    W·H × planes random float64 values for that: 1.3 GB for a 4096² atlas at n = 8, 9 GB at
    n = 64. Now at most BLEND_TIMING_PIXELS pixels, scaled."""
    import tracemalloc

    import numpy as np

    from prtcore.fit.transfer import fit_transfer
    from prtcore.report import error_vs_runtime

    rng = np.random.default_rng(0)
    D = np.abs(rng.normal(size=(6, 20, 3)))
    I = np.einsum("tp,pkc->tkc", np.abs(rng.normal(size=(50, 6))), D)
    model = fit_transfer(D, I, basis=8, ridge=1e-3)
    tracemalloc.start()
    try:
        table = error_vs_runtime(model, D[:, :2], I[:, :2], 4096 * 4096, 2, reference="x")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 200 * 2**20, peak
    assert all(r["cpu_blend_ms"] > 0 for r in table["rows"])
