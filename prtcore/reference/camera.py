"""Cameras for validation renders, and the path-traced camera-space reference.

Camera JSON (``--camera FILE``)::

    {"position": [x, y, z], "target": [x, y, z], "up": [0, 1, 0],
     "fov_y_deg": 40.0, "width": 256, "height": 256}

World space (docs/bundle.md), ``fov_y_deg`` the *vertical* field of view in degrees, ``up``
optional (default +Y). Pixel (i, j), j counted from the image's top row, looks through
normalised device coordinates ``((i + 0.5)/W·2 − 1, 1 − (j + 0.5)/H·2)``: exactly the
pixel centres OpenGL rasterises, so a render and this module's reference see the same
surface point in each pixel.

:func:`reference_image` is the ground truth for ``prtcore render``: a primary ray per
pixel centre; at a front-facing hit x, direct ``ρ/π · E_d(x)`` with ray-traced shadows
(:func:`prtcore.reference.pathtracer.reference_direct`) plus indirect by the independent path tracer
(:func:`prtcore.reference.pathtracer.reference_lightmaps`, the same estimator as the lightmap
reference, started at x instead of at a texel). Back-face hits (inside geometry) and
misses are black with A = 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.jsonfile import read_json
from prtcore.core.materials import albedo_at
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.receivers.texels import TexelSpace

#: Largest image side a camera file may ask for.
MAX_SIDE = 8192


class CameraFileError(PrtError):
    """A camera file is invalid."""


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    position, target, up : (3,) float64 world; fov_y_deg : vertical field of view in
    degrees; width, height : image size in pixels.
    """

    position: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_y_deg: float
    width: int
    height: int

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) orthonormal world axes of the camera, float64."""
        f = self.target - self.position
        f = f / np.linalg.norm(f)
        r = np.cross(f, self.up)
        r = r / np.linalg.norm(r)
        return r, np.cross(r, f), f

    def view_from_world(self) -> np.ndarray:
        """(4, 4) float64 look-at matrix (camera looks down −z, column vectors)."""
        return look_at(self.position, self.target, self.up)

    def clip_from_view(self, near: float, far: float) -> np.ndarray:
        return perspective(math.radians(self.fov_y_deg), self.aspect, near, far)

    def primary_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Origins (h·w, 3) and unit directions (h·w, 3) float64 through the pixel
        centres, row-major from the image's top row."""
        r, u, f = self.frame()
        t = math.tan(math.radians(self.fov_y_deg) / 2.0)
        i = (np.arange(self.width) + 0.5) / self.width * 2.0 - 1.0
        j = 1.0 - (np.arange(self.height) + 0.5) / self.height * 2.0
        jj, ii = np.meshgrid(j, i, indexing="ij")
        d = (f[None, :] + (ii.ravel() * t * self.aspect)[:, None] * r[None, :]
             + (jj.ravel() * t)[:, None] * u[None, :])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.position, d.shape).copy(), d


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(4, 4) float64 view matrix: world → eye space looking down −z (OpenGL)."""
    f = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(eye, np.float64)
    return m


def perspective(fov_y: float, aspect: float, near: float, far: float) -> np.ndarray:
    """(4, 4) float64 OpenGL projection (fov_y in radians)."""
    t = 1.0 / math.tan(fov_y / 2.0)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = t / aspect, t
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic(half_w: float, half_h: float, near: float, far: float) -> np.ndarray:
    m = np.eye(4)
    m[0, 0], m[1, 1] = 1.0 / half_w, 1.0 / half_h
    m[2, 2] = -2.0 / (far - near)
    m[2, 3] = -(far + near) / (far - near)
    return m


def _vec3(d: dict, key: str, file: str, default=None) -> np.ndarray:
    v = d.get(key, default)
    if not isinstance(v, list | tuple) or len(v) != 3 or not all(
            isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
            for x in v):
        raise CameraFileError(f"{file}: {key}: expected [x, y, z] of finite numbers, got {v!r}")
    return np.asarray(v, dtype=np.float64)


def camera_from_dict(d: object, file: str = "<camera>") -> Camera:
    """Validate a camera object (see the module docstring)."""
    if not isinstance(d, dict):
        raise CameraFileError(f"{file}: expected a JSON object")
    allowed = {"position", "target", "up", "fov_y_deg", "width", "height", "name"}
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise CameraFileError(f"{file}: {unknown[0]}: unknown key (allowed: "
                              f"{', '.join(sorted(allowed))})")
    for key in ("position", "target", "fov_y_deg", "width", "height"):
        if key not in d:
            raise CameraFileError(f"{file}: {key}: required")
    pos, tgt = _vec3(d, "position", file), _vec3(d, "target", file)
    up = _vec3(d, "up", file, [0.0, 1.0, 0.0])
    fwd = tgt - pos
    if not np.linalg.norm(fwd) > 0:
        raise CameraFileError(f"{file}: target: must differ from position")
    if not np.linalg.norm(np.cross(fwd / np.linalg.norm(fwd), up)) > 1e-6:
        raise CameraFileError(f"{file}: up: must not be parallel to target − position")
    fov = d["fov_y_deg"]
    if not isinstance(fov, int | float) or isinstance(fov, bool) or not 0 < fov < 180:
        raise CameraFileError(f"{file}: fov_y_deg: expected degrees in (0, 180), got {fov!r}")
    size = []
    for key in ("width", "height"):
        v = d[key]
        if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= MAX_SIDE:
            raise CameraFileError(f"{file}: {key}: expected an integer in 1..{MAX_SIDE}, "
                                  f"got {v!r}")
        size.append(v)
    return Camera(position=pos, target=tgt, up=up, fov_y_deg=float(fov), width=size[0],
                  height=size[1])


def load_camera(path: str | Path) -> Camera:
    """Read a camera JSON file."""
    data = read_json(path, lambda what: CameraFileError(f"{path}: {what}"))
    return camera_from_dict(data, str(path))


# ---------------------------------------------------------------------------------------
# Camera-space reference


@dataclass(frozen=True)
class CameraReference:
    """Path-traced view. direct, indirect, stderr : (h, w, 3) float64 linear outgoing
    radiance (stderr: standard error of the indirect estimate); alpha : (h, w) float32,
    1 where the pixel centre sees the front of a surface."""

    direct: np.ndarray
    indirect: np.ndarray
    stderr: np.ndarray
    alpha: np.ndarray

    @property
    def full(self) -> np.ndarray:
        return self.direct + self.indirect


def reference_image(scene: Scene, lights: Sequence[Light], camera: Camera, spp: int,
                    seed: int = 0, tracer: RayTracer | None = None,
                    timer: StageTimer | None = None, max_depth: int = 64) -> CameraReference:
    """Ground truth for a render: direct (ray-traced shadows) and path-traced indirect
    outgoing radiance at the surface seen through each pixel centre.

    The visible points are handed to :func:`prtcore.reference.pathtracer.reference_lightmaps` as a
    texel space of zero footprint (each "texel" is one pixel's hit point, so path origins
    are exactly that point). No buried-origin probes: a point the camera sees is outside
    geometry. spp : paths per pixel.
    """
    from prtcore.core.geometry import shading_normals
    from prtcore.reference.pathtracer import default_tracer, reference_direct, reference_lightmaps

    tracer = tracer if tracer is not None else default_tracer(scene)
    h, w = camera.height, camera.width
    origins, dirs = camera.primary_rays()
    hits = tracer.intersect(origins, dirs)
    sel = np.flatnonzero(hits.hit & hits.front)
    tri, bary = hits.triangle[sel], hits.barycentric[sel]
    gn = tracer.face_normals[tri]
    pos = tracer.surface_point(tri, bary)
    m = len(sel)
    ts = TexelSpace(
        width=w, height=h, xy=np.stack([sel % w, sel // w], axis=1).astype(np.int32),
        position=pos, normal=shading_normals(scene, tri, bary, gn), geometric_normal=gn,
        albedo=albedo_at(scene, tri, bary), triangle=tri, barycentric=bary,
        coverage=np.ones(m, np.float32), footprint=np.zeros((m, 2, 3)),
        dilate_xy=np.zeros((0, 2), np.int32), dilate_src=np.zeros(0, np.int64))
    direct = np.zeros((h * w, 3))
    indirect = np.zeros((h * w, 3))
    err = np.zeros((h * w, 3))
    if m:
        direct[sel] = reference_direct(scene, ts, lights, tracer)
        mean, se = reference_lightmaps(scene, ts, [tuple(lights)], spp, seed=seed,
                                       tracer=tracer, timer=timer, max_depth=max_depth,
                                       buried_probes=0)
        indirect[sel], err[sel] = mean[0], se[0]
    alpha = np.zeros(h * w, np.float32)
    alpha[sel] = 1.0
    return CameraReference(direct=direct.reshape(h, w, 3), indirect=indirect.reshape(h, w, 3),
                           stderr=err.reshape(h, w, 3), alpha=alpha.reshape(h, w))


def reference_view_to_exr(source: str | Path, light_path: str | Path, camera_path: str | Path,
                          out: str | Path, *, spp: int, seed: int = 0, component: str = "full",
                          quiet: bool = False) -> Path:
    """``prtcore reference SRC --camera CAM``: the path-traced view as an RGBA float EXR
    (component "full" = direct + indirect, "direct" or "indirect"). SRC: a bundle
    directory (its asset.glb, the scene a render of that bundle draws) or an asset file."""
    from prtcore.emitters.lightfile import load_light_file
    from prtcore.io.gltf.loader import load_asset
    from prtcore.io.imageio import write_exr

    if spp < 1:
        raise PrtError(f"--spp must be ≥ 1, got {spp}")
    lights = load_light_file(light_path)
    camera = load_camera(camera_path)
    source = Path(source)
    if source.is_dir():
        from prtcore.io.bundle import read_manifest

        source = source / read_manifest(source)["asset"]["file"]
    timer = StageTimer(quiet=quiet)
    with timer.stage("load"):
        scene = load_asset(source)
    ref = reference_image(scene, lights, camera, spp, seed=seed, timer=timer)
    rgb = {"full": ref.full, "direct": ref.direct, "indirect": ref.indirect}[component]
    write_exr(out, np.concatenate([rgb, ref.alpha[:, :, None]], axis=2), dtype="float")
    return Path(out)


def orbit_cameras(center: np.ndarray, radius: float, views: int, width: int, height: int,
                  *, distance: float = 2.2, elevation_rad: float = 0.5,
                  fov_y_deg: float = 40.0) -> list[Camera]:
    """``views`` cameras evenly spaced on a circle around a scene's bounding sphere
    (centre (3,), radius), ``distance`` radii from the centre and ``elevation_rad`` above
    it, looking at the centre (+y up): the camera trajectory of the learnt-transfer
    metrics."""
    c, r = np.asarray(center, np.float64), float(radius)
    cams = []
    for k in range(views):
        a = 2 * np.pi * k / views
        eye = c + distance * r * np.array([np.cos(a) * np.cos(elevation_rad),
                                           np.sin(elevation_rad),
                                           np.sin(a) * np.cos(elevation_rad)])
        cams.append(Camera(position=eye, target=c, up=np.array([0.0, 1.0, 0.0]),
                           fov_y_deg=fov_y_deg, width=width, height=height))
    return cams
