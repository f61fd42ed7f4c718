"""Benchmark: the project's path tracer on translucent objects against Mitsuba 3.

The independent check of docs/subsurface.md: a sphere (radius 1) and a cube (side 2),
each filled with a homogeneous medium at two mean free paths (0.1× and 1× the object's
size of 2), lit by a point light, seen by one camera. Both renderers use the same
boundary model, the symmetric Lambertian boundary (reflects and transmits ρ_b/π · cosθ
on both sides), expressed in Mitsuba as a Python BSDF (``mi.register_bsdf``), with the
medium as the shape's ``interior`` (``homogeneous``, RGB σ_t and single-scattering albedo,
``hg`` phase) and the ``volpath`` integrator (next-event estimation at the boundary).
The project's side is :func:`prtcore.reference.camera.reference_image` (direct +
path-traced indirect at each pixel centre; Mitsuba's box filter integrates the pixel:
silhouette pixels are left out by eroding the coverage mask by two pixels).

Noise is removed on both sides: Mitsuba renders two independent halves (noise² ≈
mean((a − b)²)/4), the path tracer reports its per-pixel standard error; corrected
err² = raw err² − both noises². Printed and written to
benchmarks/results/subsurface_mitsuba.json: per configuration the noise-corrected relative
RMSE and the relative bias of the mean, and the seconds each renderer took.

Usage: python benchmarks/subsurface_mitsuba.py [--size 40] [--spp 512] [--mi-spp 512]
       [--variant scalar_rgb]

``scalar_rgb`` runs anywhere (the Python BSDF is called per interaction: minutes);
``llvm_ad_rgb`` needs libLLVM ≥ 16 (with LLVM 15 it aborts: "Cannot select fminimum").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.core.materials import subsurface_medium  # noqa: E402
from prtcore.core.scene import Light, Material, Scene  # noqa: E402
from prtcore.reference.camera import camera_from_dict, reference_image  # noqa: E402
from prtcore.reference.pathtracer import default_tracer  # noqa: E402

BASE = np.array([0.9, 0.8, 0.7])  # base colour; t = 0.5, c_t = base → ρ_b = base / 2
MULTISCATTER = np.array([0.85, 0.7, 0.5])
LIGHT = Light(type="point", color=np.ones(3), intensity=30.0,
              position=np.array([2.0, 2.5, 1.5]))
CAMERA = {"position": [0.0, 0.8, 4.5], "target": [0.0, 0.0, 0.0], "fov_y_deg": 35.0}


def shape(kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions, normals, faces) of the unit-radius sphere (smooth normals) or the cube
    of side 2 (flat faces, split vertices)."""
    import trimesh

    if kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
        v = np.asarray(m.vertices, np.float64)
        return v, v / np.linalg.norm(v, axis=1, keepdims=True), np.asarray(m.faces, np.int64)
    m = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    m.apply_transform(trimesh.transformations.rotation_matrix(0.5, [0, 1, 0]))
    m.unmerge_vertices()
    v = np.asarray(m.vertices, np.float64)
    f = np.asarray(m.faces, np.int64)
    n = np.zeros_like(v)
    n[f.ravel()] = np.repeat(np.asarray(m.face_normals), 3, axis=0)
    return v, n, f


def prtcore_scene(kind: str, mfp: float) -> Scene:
    v, n, f = shape(kind)
    medium = subsurface_medium(MULTISCATTER, mfp, 0.0, 0.5, BASE)
    mat = Material(name="skin", base_color_factor=np.array([*BASE, 1.0]),
                   subsurface=medium)
    return Scene(source=kind, positions=v, normals=n, uv0=np.zeros((len(v), 2)), uv1=None,
                 faces=f, face_material=np.zeros(len(f), np.int32),
                 face_instance=np.zeros(len(f), np.int32), materials=(mat,))


def register_boundary(mi, dr) -> None:
    """The symmetric Lambertian boundary as a Mitsuba BSDF named "symlambert"."""

    class SymmetricLambert(mi.BSDF):
        def __init__(self, props):
            super().__init__(props)
            self.rho = mi.Color3f(props["rho_r"], props["rho_g"], props["rho_b"])
            flags = (mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.DiffuseTransmission
                     | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide)
            self.m_components = [flags]
            self.m_flags = flags

        def _rho(self, si, active):
            return self.rho

        def sample(self, ctx, si, sample1, sample2, active=True):
            local = mi.warp.square_to_cosine_hemisphere(sample2)
            side = dr.select(mi.Frame3f.cos_theta(si.wi) >= 0, 1.0, -1.0)
            transmit = sample1 < 0.5
            z = dr.select(transmit, -side, side) * dr.abs(local.z)
            wo = mi.Vector3f(local.x, local.y, z)
            bs = mi.BSDFSample3f()
            bs.wo = wo
            bs.pdf = 0.5 * dr.abs(z) * dr.inv_pi
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+dr.select(
                transmit, mi.UInt32(+mi.BSDFFlags.DiffuseTransmission),
                mi.UInt32(+mi.BSDFFlags.DiffuseReflection)))
            bs.sampled_component = mi.UInt32(0)
            # f·|cos|/pdf = (ρ/π)|cos| / (½|cos|/π) = 2ρ
            return bs, dr.select(bs.pdf > 0, 2.0 * self._rho(si, active), 0.0)

        def eval(self, ctx, si, wo, active=True):
            return self._rho(si, active) * dr.inv_pi * dr.abs(mi.Frame3f.cos_theta(wo))

        def pdf(self, ctx, si, wo, active=True):
            return 0.5 * dr.inv_pi * dr.abs(mi.Frame3f.cos_theta(wo))

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def to_string(self):
            return "SymmetricLambert"

    mi.register_bsdf("symlambert", lambda props: SymmetricLambert(props))


def mitsuba_render(mi, kind: str, mfp: float, size: int, spp: int, seed: int) -> np.ndarray:
    """Mitsuba's (size, size, 3) linear RGB image of ``kind`` at mean free path ``mfp``:
    volpath, the symmetric Lambertian boundary, the medium as the mesh's interior."""
    import tempfile

    import trimesh

    v, n, f = shape(kind)
    medium = subsurface_medium(MULTISCATTER, mfp, 0.0, 0.5, BASE)
    rho = 0.5 * (0.5 * BASE + 0.5 * BASE)  # ρ_b = ½((1 − t)·base + t·c_t), t = ½, c_t = base
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "obj.ply"
        trimesh.Trimesh(v, f, vertex_normals=n, process=False).export(path)
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "volpath", "max_depth": 4096, "rr_depth": 64},
            "sensor": {
                "type": "perspective", "fov": CAMERA["fov_y_deg"], "fov_axis": "y",
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=CAMERA["position"], target=CAMERA["target"], up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": size, "height": size,
                         "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            },
            "light": {"type": "point", "position": LIGHT.position.tolist(),
                      "intensity": {"type": "rgb",
                                    "value": (LIGHT.color * LIGHT.intensity).tolist()}},
            "obj": {
                "type": "ply", "filename": str(path), "face_normals": kind == "cube",
                "bsdf": {"type": "symlambert", "rho_r": float(rho[0]),
                         "rho_g": float(rho[1]), "rho_b": float(rho[2])},
                "interior": {"type": "homogeneous", "scale": float(medium.sigma_t.max()),
                             "sigma_t": {"type": "rgb", "value": (
                                 medium.sigma_t / medium.sigma_t.max()).tolist()},
                             "albedo": {"type": "rgb", "value": medium.albedo.tolist()},
                             "phase": {"type": "hg", "g": float(medium.anisotropy)}},
            },
        })
        return np.asarray(mi.render(scene), dtype=np.float64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=40)
    ap.add_argument("--spp", type=int, default=512, help="path tracer paths per pixel")
    ap.add_argument("--mi-spp", type=int, default=512, help="Mitsuba samples per pixel")
    ap.add_argument("--variant", default="scalar_rgb")
    args = ap.parse_args()
    import drjit as dr
    import mitsuba as mi
    from scipy.ndimage import binary_erosion

    mi.set_variant(args.variant)
    register_boundary(mi, dr)
    cam = camera_from_dict({**CAMERA, "width": args.size, "height": args.size})
    rows = []
    for kind in ("sphere", "cube"):
        for mfp in (0.2, 2.0):
            scene = prtcore_scene(kind, mfp)
            t0 = time.perf_counter()
            ref = reference_image(scene, [LIGHT], cam, args.spp, seed=1,
                                  tracer=default_tracer(scene))
            t_ours = time.perf_counter() - t0
            ours = ref.direct + ref.indirect
            t0 = time.perf_counter()
            a = mitsuba_render(mi, kind, mfp, args.size, args.mi_spp // 2, seed=11)
            b = mitsuba_render(mi, kind, mfp, args.size, args.mi_spp // 2, seed=12)
            t_mi = time.perf_counter() - t0
            mask = binary_erosion(ref.alpha > 0, iterations=2)
            o, ma, mb = ours[mask], a[mask], b[mask]
            m = (ma + mb) / 2
            noise_mi = np.mean((ma - mb) ** 2) / 4
            noise_ours = np.mean(ref.stderr[mask] ** 2)
            raw = np.mean((o - m) ** 2)
            rms = np.sqrt(np.mean(m ** 2))
            row = {"shape": kind, "mean_free_path": mfp, "pixels": int(mask.sum()),
                   "rrmse": float(np.sqrt(max(raw - noise_mi - noise_ours, 0.0)) / rms),
                   "rrmse_raw": float(np.sqrt(raw) / rms),
                   "noise_mitsuba": float(np.sqrt(noise_mi) / rms),
                   "noise_ours": float(np.sqrt(noise_ours) / rms),
                   "bias": float(o.mean() / m.mean() - 1.0),
                   "bias_per_channel": (o.mean(axis=0) / m.mean(axis=0) - 1.0).tolist(),
                   "seconds_ours": t_ours, "seconds_mitsuba": t_mi}
            rows.append(row)
            print(f"{kind:6s} mfp {mfp:4.1f}: rRMSE {row['rrmse']:.4f} (raw "
                  f"{row['rrmse_raw']:.4f}, noise mitsuba {row['noise_mitsuba']:.4f}, "
                  f"ours {row['noise_ours']:.4f}), bias {row['bias']:+.4f} "
                  f"{np.round(row['bias_per_channel'], 4).tolist()}; {t_ours:.0f} s ours, "
                  f"{t_mi:.0f} s Mitsuba", flush=True)
            out = ROOT / "benchmarks" / "results"
            out.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(out / f"subsurface_mitsuba_{kind}_{mfp}.npz", ours=ours,
                                mitsuba=(a + b) / 2, mask=mask)
    (ROOT / "benchmarks" / "results" / "subsurface_mitsuba.json").write_text(json.dumps(
        {"args": vars(args), "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
