"""The bundle and the CPU runtime: packing round trip against the fit's own reconstruction,
an end-to-end bake of the Cornell box, atomicity, determinism, the manifest schema."""

import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from scenes import TINY_SPEC

from prtcore import pipeline
from prtcore.core.errors import BundleError, PrtError
from prtcore.core.raytrace import RayTracer
from prtcore.core.spec import parse_spec
from prtcore.emitters.lightfile import load_light_file
from prtcore.fit.transfer import fit_transfer, reconstruct
from prtcore.io.bundle import (
    RuntimeData,
    basis_planes,
    load_runtime,
    planes_layout,
    read_manifest,
    verify_bundle,
    write_basis_files,
    write_bundle,
)
from prtcore.io.gltf.loader import load_asset
from prtcore.runtime.cpu import blend, plane_weights, relight

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"
SCHEMA = json.loads((ROOT / "prtcore" / "data" / "manifest.schema.json").read_text())



@pytest.fixture(scope="module")
def tiny_bundle(tmp_path_factory):
    out = tmp_path_factory.mktemp("bake") / "bundle"
    return pipeline.bake(CORNELL, parse_spec(TINY_SPEC), out, quiet=True)


@pytest.mark.parametrize(("channels", "gamma"), [("mono", None), ("rgb", None),
                                                 ("mono", 2.2)])
def test_packed_planes_reproduce_the_fit(tmp_path, channels, gamma):
    """Planes written to EXR and read back, blended with the runtime's plane weights,
    equal fit.reconstruct — two implementations of the runtime formula agree."""
    rng = np.random.default_rng(0)
    T, P, K, side = 36, 10, 40, 6
    transport = np.abs(rng.normal(size=(T, P)))
    D = np.abs(rng.normal(size=(P, K, 3)))
    I = np.einsum("tp,pkc->tkc", transport, D)
    model = fit_transfer(D, I, basis=6, ridge=1e-6, channels=channels, gamma=gamma)
    planes = basis_planes(model.mean, model.basis, model.channels)
    files = write_basis_files(tmp_path, planes.reshape(side, side, -1), "float")
    from prtcore.io.imageio import read_image
    img = np.concatenate([read_image(tmp_path / f) for f in files], axis=2)
    el, ch = planes_layout(model.channels, model.basis.shape[1])
    data = RuntimeData(planes=img[:, :, :planes.shape[1]], plane_element=el,
                       plane_channel=ch, transfer=model.transfer, offset=model.offset,
                       gamma=model.gamma, coverage=np.ones((side, side), bool),
                       cluster_position=np.zeros((0, 3)), cluster_normal=np.zeros((0, 3)),
                       cluster_albedo=np.zeros((0, 3)), cluster_owner=np.zeros(0, int),
                       point_count=P)
    x = np.abs(rng.normal(size=(P, 3)))
    for n in (1, 3, 6):
        ours = blend(data, plane_weights(data, x, n)).reshape(T, 3)
        # the runtime clamps negative light at 0 (core/formula.py); the fit is linear
        np.testing.assert_allclose(ours, np.maximum(reconstruct(model, x, n=n), 0.0),
                                   rtol=2e-5, atol=1e-6)


def test_bake_writes_a_valid_bundle(tiny_bundle):
    m = read_manifest(tiny_bundle)
    jsonschema.validate(m, SCHEMA)
    verify_bundle(tiny_bundle, m)
    assert m["basis"]["count"] == 8
    assert m["atlas"]["width"] == m["atlas"]["height"] == 32
    assert m["points"]["count"] == 32
    assert m["transfer"]["matrix"]["shape"] == [3, 7, 32]
    for f in ["asset.glb", "coverage.exr", "report.json", "report.png", *m["basis"]["files"]]:
        assert (tiny_bundle / f).is_file(), f
    scene = load_asset(tiny_bundle / "asset.glb")
    assert scene.uv1 is not None
    assert scene.triangle_count == m["asset"]["triangles"]
    rows = json.loads((tiny_bundle / "report.json").read_text())["table"]["rows"]
    assert [r["n"] for r in rows] == sorted(r["n"] for r in rows)
    assert all(np.isfinite(r["heldout_rmse_mean"]) for r in rows)


def test_relight_is_linear_and_respects_coverage(tiny_bundle):
    data = load_runtime(tiny_bundle)
    m = read_manifest(tiny_bundle)
    scene = load_asset(tiny_bundle / "asset.glb")
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    light = load_light_file(tiny_bundle / "holdout_lights.json")[0]
    a = relight(data, [light], tracer)
    assert a.shape == (32, 32, 4)
    assert np.isfinite(a).all()
    assert int(a[:, :, 3].sum()) == m["atlas"]["covered_texels"]
    import dataclasses
    b = relight(data, [dataclasses.replace(light, intensity=light.intensity * 1e3)], tracer)
    np.testing.assert_allclose(b[:, :, :3], 1e3 * a[:, :, :3], rtol=1e-4, atol=1e-7)
    # a light that reaches no measurement point relights to exactly zero
    dark = dataclasses.replace(light, position=np.array([0.0, 50.0, 0.0]), range=1.0)
    assert np.abs(relight(data, [dark], tracer)[:, :, :3]).max() == 0.0


def test_same_spec_same_bundle(tiny_bundle, tmp_path):
    again = pipeline.bake(CORNELL, parse_spec(TINY_SPEC), tmp_path / "again", quiet=True)
    a, b = read_manifest(tiny_bundle), read_manifest(again)
    assert a["checksums"] == b["checksums"]
    for f in a["checksums"]:
        assert (tiny_bundle / f).read_bytes() == (again / f).read_bytes(), f


def test_failed_bake_leaves_nothing(tmp_path, monkeypatch):
    import prtcore.transport.dataset

    def boom(*args, **kwargs):
        raise PrtError("transport exploded")

    monkeypatch.setattr(prtcore.transport.dataset, "light_configurations", boom)
    out = tmp_path / "b"
    with pytest.raises(PrtError, match="exploded"):
        pipeline.bake(CORNELL, parse_spec(TINY_SPEC), out, quiet=True)
    assert list(tmp_path.iterdir()) == []


def test_write_bundle_is_atomic_and_guarded(tmp_path):
    out = tmp_path / "b"

    def ok(d):
        (d / "x.bin").write_bytes(b"1")
        return {"schema": "prtcore.bundle", "version": 1}

    def fails(d):
        (d / "x.bin").write_bytes(b"2")
        raise RuntimeError("disk full")

    write_bundle(out, ok)
    with pytest.raises(PrtError, match="already exists"):
        write_bundle(out, ok)
    with pytest.raises(RuntimeError):
        write_bundle(out, fails, force=True)
    assert (out / "x.bin").read_bytes() == b"1"  # the old bundle survives a failed rebake
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]


def test_corrupt_bundle_is_refused(tiny_bundle, tmp_path):
    import shutil
    copy = tmp_path / "copy"
    shutil.copytree(tiny_bundle, copy)
    (copy / "transfer.bin").write_bytes(b"\0" * 8)
    with pytest.raises(BundleError, match=r"transfer\.bin"):
        verify_bundle(copy)
    with pytest.raises(BundleError, match=r"transfer\.bin"):
        load_runtime(copy)
    (copy / "manifest.json").write_text("{}")
    with pytest.raises(BundleError, match="schema"):
        read_manifest(copy)
