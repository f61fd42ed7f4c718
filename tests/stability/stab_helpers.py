"""Shared helpers of the stability suite: scene builders, tiny specs, output checks.

Every check that a bundle is "finite" goes through :func:`assert_bundle_finite`, which
reads every numeric file a bake writes (basis planes, coverage, transfer, offset, points)
and the numbers of report.json / manifest.json (where a non-finite float would have been
written as null).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import trimesh
from scenes import tiny_spec

from prtcore import pipeline
from prtcore.core.spec import parse_spec
from prtcore.io.bundle import load_runtime, read_manifest, verify_bundle
from prtcore.io.imageio import read_image
from prtcore.scenes.cornell import cornell_box

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"

#: The room's point-light family: inside the box, clear of the walls.
ROOM_BOX = [[-0.6, 1.3, -0.6], [0.6, 1.7, 0.6]]

#: TINY_SPEC (tests/scenes.py) with the room's light family and 6 held-out lights.
TINY = tiny_spec(lights={"count": 24, "holdout": 6, "families": [
    {"type": "point", "position": {"box": ROOM_BOX}, "intensity": {"uniform": [0.5, 3.0]}}]})


def spec_with(**changes) -> dict:
    """TINY with top-level sections replaced/merged: spec_with(fit={"gamma": 2.2})."""
    spec = copy.deepcopy(TINY)
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(spec.get(key), dict):
            spec[key] = {**spec[key], **copy.deepcopy(value)}
        else:
            spec[key] = copy.deepcopy(value)
    return spec


def bake(asset: Path, spec: dict, out: Path, **kw) -> Path:
    return pipeline.bake(asset, parse_spec(spec), out, quiet=True, **kw)


def write_scene(scene: trimesh.Scene, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(scene.export(file_type="glb", include_normals=True))
    return path


def scaled_cornell(path: Path, scale: float) -> Path:
    """The Cornell box with every coordinate multiplied by ``scale``."""
    scene = cornell_box()
    scene.apply_transform(np.diag([scale, scale, scale, 1.0]))
    return write_scene(scene, path)


def _numbers(x, where: str = ""):
    """Every number (and null) in parsed JSON, with its path."""
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _numbers(v, f"{where}.{k}")
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _numbers(v, f"{where}[{i}]")
    elif isinstance(x, int | float) and not isinstance(x, bool):
        yield where, float(x)


def assert_bundle_finite(bundle: Path) -> dict:
    """Every numeric output of a bundle is finite; returns the manifest."""
    m = read_manifest(bundle)
    verify_bundle(bundle, m)
    for f in [*m["basis"]["files"], m["atlas"]["coverage"]]:
        img = read_image(bundle / f)
        assert np.isfinite(img).all(), f"{f}: non-finite values"
    data = load_runtime(bundle, m)
    for name in ("planes", "transfer", "offset", "cluster_position", "cluster_normal",
                 "cluster_albedo"):
        assert np.isfinite(getattr(data, name)).all(), f"{name}: non-finite values"
    for desc in (m["points"]["points"],):
        a = np.fromfile(bundle / desc["file"], dtype=desc["dtype"])
        assert np.isfinite(a).all(), f"{desc['file']}: non-finite values"
    report = json.loads((bundle / "report.json").read_text())
    for doc, name in ((m, "manifest"), (report, "report")):
        for where, v in _numbers(doc):
            assert np.isfinite(v), f"{name}{where} = {v}"
    # non-finite floats are written as null: a null where the error table has a number
    # would hide a NaN
    for row in report["table"]["rows"]:
        for key in ("heldout_rmse_mean", "heldout_rmse_max", "projection_bound_mean"):
            assert row[key] is not None, f"report table n={row['n']}: {key} is null"
    return m


def heldout_rmse(bundle: Path) -> dict[int, float]:
    rows = json.loads((bundle / "report.json").read_text())["table"]["rows"]
    return {r["n"]: r["heldout_rmse_mean"] for r in rows}


def cornell_with(path: Path, base_color: dict | None = None,
                 emissive: dict | None = None) -> Path:
    """The Cornell box with materials edited in the glTF JSON (trimesh clips factors to
    [0, 1]; the glTF file itself can say anything): ``base_color`` maps a material name
    ("floor", "ceiling", "back", "left", "right", "tall_block", "short_block", or "*")
    to an RGB factor, ``emissive`` to an emissiveFactor."""
    import pygltflib

    write_scene(cornell_box(), path)
    g = pygltflib.GLTF2().load(str(path))
    for m in g.materials:
        for table, setter in ((base_color or {}, "base"), (emissive or {}, "emissive")):
            rgb = table.get(m.name, table.get("*"))
            if rgb is None:
                continue
            if setter == "base":
                m.pbrMetallicRoughness.baseColorFactor = [*map(float, rgb), 1.0]
            else:
                m.emissiveFactor = [float(c) for c in rgb]
    g.save(str(path))
    return path


def result_files(bundle: Path) -> dict[str, bytes]:
    """The files that carry the bake's result (basis planes, transfer, offset)."""
    m = read_manifest(bundle)
    names = [*m["basis"]["files"], m["transfer"]["matrix"]["file"],
             m["transfer"]["offset"]["file"]]
    return {n: (bundle / n).read_bytes() for n in names}


class Transport:
    """The pipeline's intake and transport for one asset + spec, with the gather operator
    traced once, so that any set of lights can be turned into (D, I) cheaply — the same
    steps as :func:`prtcore.transport.dataset.bake_dataset`."""

    def __init__(self, asset: Path, spec: dict):
        from prtcore.core.raytrace import RayTracer
        from prtcore.pipeline import run_intake
        from prtcore.transport.dataset import trace_operators

        self.spec = parse_spec(spec)
        self.intake = run_intake(asset, self.spec, quiet=True)
        sc = self.intake.scene
        self.tracer = RayTracer(sc.positions, sc.faces, sc.radius)
        self.traced = trace_operators(sc, self.intake.texels, self.tracer, self.spec.transport)

    def configurations(self):
        from prtcore.emitters.families import sample_configurations

        sc = self.intake.scene
        return sample_configurations(self.spec.lights, sc.center, sc.radius, sc.lights)

    def dataset(self, lights) -> tuple[np.ndarray, np.ndarray]:
        """D (P, K, 3) float32 and I (T, K, 3) float32 for ``lights``."""
        from prtcore.transport.dataset import light_texels
        from prtcore.transport.direct import direct_radiance

        sc, tx, pts = self.intake.scene, self.intake.texels, self.intake.points
        cl = direct_radiance(sc, self.tracer, lights, pts.cluster_position,
                             pts.cluster_normal, pts.cluster_albedo)
        k = len(lights)
        d = pts.average_clusters(cl.reshape(len(cl), 3 * k).astype(np.float64))
        D = d.reshape(pts.count, k, 3).astype(np.float32)
        I = light_texels(sc, tx, self.tracer, self.traced, lights, self.spec.transport).indirect
        return D, I
