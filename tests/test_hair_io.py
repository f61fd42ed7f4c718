"""Hair intake (issue 16): cyHair ``.hair`` and USD BasisCurves readers, hardened like the
glTF loader — limits before allocation, NaN refused, one-line errors naming file and field."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from prtcore.core.errors import AssetError, LimitExceeded, UnsupportedAsset
from prtcore.core.hair import make_hair
from prtcore.core.limits import IntakeLimits
from prtcore.io.hair import is_hair_file, load_hair, read_hair, write_hair, write_usd_hair
from prtcore.io.hair.yuksel import HEADER
from prtcore.scenes.hair import hairball


def _small():
    return make_hair([np.array([[0, 0, 0], [0, 1, 0], [0, 2, 0.5]]),
                      np.array([[1, 0, 0], [1, 1, 0]])], thickness=[0.01, 0.02],
                     color=[[0.1, 0.2, 0.3], [0.9, 0.8, 0.7]])


def test_round_trip_keeps_every_array(tmp_path):
    h = _small()
    back = read_hair(write_hair(tmp_path / "a.hair", h))
    np.testing.assert_array_equal(back.offsets, h.offsets)
    np.testing.assert_allclose(back.points, h.points, rtol=1e-7)
    np.testing.assert_allclose(back.thickness, h.thickness, rtol=1e-7)
    np.testing.assert_allclose(back.color, h.color, rtol=1e-7)
    assert back.strand_count == 2 and back.point_count == 5
    np.testing.assert_allclose(back.strand_length, [1 + np.hypot(1, 0.5), 1.0], rtol=1e-6)


def test_round_trip_hairball(tmp_path):
    h = hairball(strands=500, seed=3)
    back = load_hair(write_hair(tmp_path / "ball.hair", h))
    np.testing.assert_array_equal(back.offsets, h.offsets)
    np.testing.assert_allclose(back.points, h.points, atol=1e-7)


def _raw(strands, points, flags, d_seg=2, d_th=0.01, d_col=(0.5, 0.5, 0.5)):
    return HEADER.pack(b"HAIR", strands, points, flags, d_seg, d_th, 0.0, *d_col, b"t")


def test_defaults_apply_when_arrays_are_absent(tmp_path):
    p = tmp_path / "d.hair"
    pts = np.arange(2 * 3 * 3, dtype="<f4")
    p.write_bytes(_raw(2, 6, 0b10, d_seg=2, d_th=0.004, d_col=(0.2, 0.4, 0.6)) + pts.tobytes())
    h = read_hair(p)
    np.testing.assert_array_equal(h.offsets, [0, 3, 6])
    np.testing.assert_allclose(h.thickness, 0.004, rtol=1e-6)
    np.testing.assert_allclose(h.color, np.tile([0.2, 0.4, 0.6], (6, 1)), rtol=1e-6)


@pytest.mark.parametrize("mutate, field", [
    (lambda b: b"HAIx" + b[4:], "header.signature"),
    (lambda b: b[:60], "header"),
    (lambda b: b + b"\0\0\0\0", "header"),
    (lambda b: b[:12] + struct.pack("<I", 0b10) + b[16:], "header"),  # arrays missing
    (lambda b: b[:12] + struct.pack("<I", 0b100010) + b[16:], "header.arrays"),
])
def test_malformed_headers_are_refused_naming_the_field(tmp_path, mutate, field):
    good = write_hair(tmp_path / "g.hair", _small()).read_bytes()
    p = tmp_path / "bad.hair"
    p.write_bytes(mutate(good))
    with pytest.raises(AssetError) as e:
        read_hair(p)
    assert str(p) in str(e.value) and f": {field}:" in str(e.value)
    assert "\n" not in str(e.value)


def test_nan_point_is_refused_with_its_index(tmp_path):
    h = _small()
    pts = h.points.copy()
    pts[3, 1] = np.nan
    p = write_hair(tmp_path / "nan.hair", type(h)(h.offsets, pts, h.thickness, h.color))
    with pytest.raises(AssetError, match=r"nan\.hair: points\[3\]: is not finite"):
        read_hair(p)


def test_bad_thickness_and_segment_sum_are_refused(tmp_path):
    h = _small()
    p = write_hair(tmp_path / "t.hair", type(h)(h.offsets, h.points, -h.thickness, h.color))
    with pytest.raises(AssetError, match=r"thickness\[0\]: is not positive"):
        read_hair(p)
    raw = bytearray(write_hair(tmp_path / "s.hair", h).read_bytes())
    raw[128:130] = struct.pack("<H", 3)  # strand 0 claims 3 segments: sums disagree
    p.write_bytes(bytes(raw))
    with pytest.raises(AssetError, match=r"header\.point_count"):
        read_hair(p)


def test_limits_are_checked_before_arrays_are_read(tmp_path):
    p = tmp_path / "huge.hair"
    # claims 10^9 points but holds none: refused by the limit, not by a failed allocation
    p.write_bytes(_raw(1, 10**9, 0b10))
    with pytest.raises(LimitExceeded, match=r"header.point_count: .*max_hair_points="):
        read_hair(p)
    p.write_bytes(_raw(10, 30, 0b10))
    with pytest.raises(LimitExceeded, match=r"header.hair_count: .*max_strands=5"):
        read_hair(p, IntakeLimits(max_strands=5))


def test_unknown_suffix_is_refused():
    assert is_hair_file("x.HAIR") and is_hair_file("a.usda") and not is_hair_file("a.glb")
    with pytest.raises(UnsupportedAsset, match="not a hair format"):
        load_hair("x.abc")


# -- USD BasisCurves ----------------------------------------------------------------------

pytest.importorskip("pxr", reason="usd-core is a pinned dependency")


def _usda(tmp_path, body: str, stage: str = "    metersPerUnit = 1\n", name: str = "h.usda"):
    """A .usda file; USD's default unit is the centimetre, so the stage states metres."""
    p = tmp_path / name
    p.write_text(f'#usda 1.0\n(\n    upAxis = "Y"\n{stage})\n{body}\n')
    return p


LINEAR = """
def BasisCurves "curves" {
    uniform token type = "linear"
    int[] curveVertexCounts = [3, 2]
    point3f[] points = [(0, 0, 0), (0, 1, 0), (0, 2, 0), (1, 0, 0), (1, 1, 0)]
    float[] widths = [0.01, 0.02, 0.03, 0.04, 0.05] (interpolation = "vertex")
    color3f[] primvars:displayColor = [(0.1, 0.2, 0.3), (0.7, 0.8, 0.9)] (
        interpolation = "uniform")
}"""


def test_usd_linear_curves(tmp_path):
    h = load_hair(_usda(tmp_path, LINEAR))
    np.testing.assert_array_equal(h.offsets, [0, 3, 5])
    np.testing.assert_allclose(h.points[4], [1, 1, 0], atol=1e-7)
    np.testing.assert_allclose(h.thickness, [0.01, 0.02, 0.03, 0.04, 0.05], rtol=1e-6)
    np.testing.assert_allclose(h.color[:3], np.tile([0.1, 0.2, 0.3], (3, 1)), rtol=1e-6)
    np.testing.assert_allclose(h.color[3:], np.tile([0.7, 0.8, 0.9], (2, 1)), rtol=1e-6)


def test_usd_units_up_axis_and_transform(tmp_path):
    body = """
def Xform "root" {
    double3 xformOp:translate = (0, 0, 100)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def BasisCurves "c" {
        uniform token type = "linear"
        int[] curveVertexCounts = [2]
        point3f[] points = [(0, 0, 0), (0, 0, 10)]
        float[] widths = [0.5] (interpolation = "constant")
    }
}"""
    h = load_hair(_usda(tmp_path, body, '    upAxis = "Z"\n    metersPerUnit = 0.01\n'))
    # Z-up centimetres: (0, 0, 100) cm → (0, 1, 0) m in +Y up
    np.testing.assert_allclose(h.points, [[0, 1, 0], [0, 1.1, 0]], atol=1e-9)
    np.testing.assert_allclose(h.thickness, 0.005, rtol=1e-6)


@pytest.mark.parametrize("basis, count", [("bspline", 6), ("catmullRom", 6), ("bezier", 7)])
def test_usd_cubic_curves_are_tessellated_on_the_curve(tmp_path, basis, count):
    cv = ", ".join(f"({i}, {0.5 * i * i}, 0)" for i in range(count))
    body = f"""
def BasisCurves "c" {{
    uniform token type = "cubic"
    uniform token basis = "{basis}"
    int[] curveVertexCounts = [{count}]
    point3f[] points = [{cv}]
}}"""
    h = load_hair(_usda(tmp_path, body))
    x, y = h.points[:, 0], h.points[:, 1]
    assert h.point_count > count
    if basis == "catmullRom":  # reproduces quadratics, through control points 1 … n − 2
        np.testing.assert_allclose(y, 0.5 * x ** 2, atol=1e-6)
        np.testing.assert_allclose(x[[0, -1]], [1, count - 2], atol=1e-9)
    elif basis == "bspline":  # Σ N_i(x) i² = x² + 1/3 for the uniform cubic B-spline
        np.testing.assert_allclose(y, 0.5 * x ** 2 + 1 / 6, atol=1e-6)
    else:  # bezier: interpolates the ends of each segment (control points 0, 3, 6)
        np.testing.assert_allclose(h.points[[0, 4, 8], :2], [[0, 0], [3, 4.5], [6, 18]],
                                   atol=1e-6)


@pytest.mark.parametrize("edit, field", [
    (lambda s: s.replace("(0, 1, 0), (0, 2, 0)", "(0, nan, 0), (0, 2, 0)"),
     r"/curves\.points\[1\]: is not finite"),
    (lambda s: s.replace("[3, 2]", "[3, 3]"), r"/curves\.points: 5 points"),
    (lambda s: s.replace("[3, 2]", "[3, 1]"), r"/curves\.curveVertexCounts\[1\]"),
    (lambda s: s.replace("0.01, 0.02, 0.03, 0.04, 0.05", "0.01, 0.02"), r"/curves\.widths"),
    (lambda s: s.replace('"linear"', '"linear"\n    uniform token wrap = "periodic"'),
     r"/curves\.wrap"),
])
def test_usd_refusals_name_prim_and_attribute(tmp_path, edit, field):
    p = _usda(tmp_path, edit(LINEAR))
    with pytest.raises(AssetError, match=field) as e:
        load_hair(p)
    assert str(e.value).startswith(str(p)) and "\n" not in str(e.value)


def test_usd_strand_limit(tmp_path):
    with pytest.raises(LimitExceeded, match=r"curveVertexCounts: 2 strands .*max_strands=1"):
        load_hair(_usda(tmp_path, LINEAR), IntakeLimits(max_strands=1))


def test_usd_unreadable_and_empty(tmp_path):
    bad = tmp_path / "bad.usda"
    bad.write_text("not usd at all")
    with pytest.raises(AssetError, match=r"bad\.usda"):
        load_hair(bad)
    with pytest.raises(AssetError, match="no BasisCurves"):
        load_hair(_usda(tmp_path, 'def Xform "x" {}', name="e.usda"))


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_usd_round_trip(tmp_path, suffix):
    h = hairball(strands=200, seed=5)
    back = load_hair(write_usd_hair(tmp_path / f"ball{suffix}", h))
    np.testing.assert_array_equal(back.offsets, h.offsets)
    np.testing.assert_allclose(back.points, h.points, atol=1e-7)
    np.testing.assert_allclose(back.thickness, h.thickness, rtol=1e-6)
    np.testing.assert_allclose(back.color, h.color, rtol=1e-6)


def test_usd_layers_that_compose_other_files_are_refused(tmp_path):
    """USD would open a sublayer or reference from anywhere on disk: refused first."""
    _usda(tmp_path, LINEAR, name="inner.usda")
    outer = _usda(tmp_path, 'def "x" (references = @./inner.usda@) {}', name="outer.usda")
    with pytest.raises(UnsupportedAsset, match=r"outer\.usda: the layer composes other files"):
        load_hair(outer)
    sub = tmp_path / "sub.usda"
    sub.write_text('#usda 1.0\n(\n    subLayers = [@/etc/passwd@]\n)\n')
    with pytest.raises(UnsupportedAsset, match="composes other files"):
        load_hair(sub)
