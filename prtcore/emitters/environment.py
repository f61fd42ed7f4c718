"""Distant environment lighting: equirect maps, their SH projection, importance sampling.

An :class:`Environment` is radiance arriving from infinitely far away, stored as an
equirectangular map (the convention of :mod:`prtcore.core.sh`, which is Mitsuba 3's
``envmap``) and turned into the world by a rotation. It is piecewise constant per pixel:
:meth:`Environment.radiance` looks up the pixel a direction falls in, and
:class:`EnvironmentSampler` draws directions with a density proportional to each pixel's
luminance (uniform in solid angle inside a pixel), so its pdf is exact for that function.

An environment is not a punctual light (each surface point sees a whole sphere of
directions), so it is not a member of the punctual-emitter registry
(:mod:`prtcore.emitters.base`): classic SH-PRT (:mod:`prtcore.methods.sh_prt`) consumes its
SH coefficients, and the environment reference
(:mod:`prtcore.reference.environment`) samples it. :func:`light_sh` projects a directional
light to SH so that the two kinds of lighting share one runtime.

Units: radiance in the project's radiometric units (a directional light's ``intensity`` is
an irradiance at normal incidence); outgoing radiance of a diffuse surface is
``ρ/π · ∫ L(ω) V(ω) cos θ dω``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from prtcore.core import sh
from prtcore.core.errors import LightFileError
from prtcore.core.scene import Light
from prtcore.emitters.base import light_axis

#: Rec. 709 luminance weights (importance of a pixel for sampling)
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
#: The largest environment map accepted (pixels), checked before reading the pixels.
MAX_PIXELS = 8192 * 4096


@dataclass(frozen=True, eq=False)
class Environment:
    """Distant radiance.

    image : (H, W, 3) float64 linear RGB radiance of an equirect map (row 0 at the top);
    rotation : (3, 3) float64 proper rotation, world direction = rotation @ map direction;
    name : where it came from (a file name, a family member).
    """

    image: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    name: str = ""

    def rotated(self, rotation: np.ndarray) -> Environment:
        """The same map turned by ``rotation`` (3, 3) in the world (applied after this one)."""
        return replace(self, rotation=np.asarray(rotation, np.float64) @ self.rotation)

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """(n, 3) float64 radiance arriving from world ``directions`` (n, 3) unit (the
        direction toward the environment), nearest pixel."""
        h, w, _ = self.image.shape
        uv = sh.equirect_uv(np.asarray(directions, np.float64) @ self.rotation)
        col = np.minimum((uv[:, 0] * w).astype(np.int64), w - 1)
        row = np.minimum((uv[:, 1] * h).astype(np.int64), h - 1)
        return self.image[row, col]

    def sh_coefficients(self, bands: int) -> np.ndarray:
        """(L², 3) float64 SH coefficients of the world-space radiance (the map projected
        with exact pixel solid angles, then rotated by :func:`prtcore.core.sh.rotate`)."""
        return sh.rotate(sh.project_equirect(self.image, bands), self.rotation)


def load_environment(path: str | Path, *, rotation: np.ndarray | None = None,
                     scale: float = 1.0) -> Environment:
    """Read an equirect EXR/HDR (anything OpenImageIO reads) as an :class:`Environment`.

    The first three channels are RGB (a one-channel map is grey); the map must be twice as
    wide as it is tall, finite and ≥ 0. Errors name the file.
    """
    from prtcore.io.imageio import image_size, read_image

    height, width, _ = image_size(path)
    if width * height > MAX_PIXELS:
        raise LightFileError(f"{path}: environment map {width}×{height} is larger "
                             f"than {MAX_PIXELS} pixels")
    if width != 2 * height:
        raise LightFileError(f"{path}: an equirect environment map is twice as wide as tall, "
                             f"got {width}×{height}")
    img = read_image(path).astype(np.float64)
    rgb = np.repeat(img[..., :1], 3, axis=2) if img.shape[2] < 3 else img[..., :3]
    if not np.isfinite(rgb).all() or (rgb < 0).any():
        raise LightFileError(f"{path}: environment radiance must be finite and ≥ 0")
    return Environment(rgb * float(scale), np.eye(3) if rotation is None
                       else np.asarray(rotation, np.float64), Path(path).name)


class EnvironmentSampler:
    """Directions drawn ∝ pixel luminance (uniform in solid angle inside a pixel).

    The pdf of a direction in pixel p is ``P_p / Ω_p`` (P_p the pixel's probability, Ω_p
    its solid angle); pixels whose luminance is 0 are never drawn (their radiance is 0, so
    an estimator that weights by radiance / pdf stays unbiased).
    """

    def __init__(self, env: Environment):
        self.env = env
        h, w, _ = env.image.shape
        _, area = sh.equirect_directions(h, w)
        weight = np.clip(env.image @ LUMINANCE, 0.0, None) * area
        total = weight.sum()
        if not total > 0:
            raise LightFileError(f"{env.name or 'environment'}: a black environment cannot "
                                 f"be importance sampled")
        self._prob = (weight / total).ravel()
        self._cdf = np.cumsum(self._prob)
        self._cdf[-1] = 1.0
        self._density = (weight / total / area).ravel()  # pdf per solid angle, per pixel
        self._shape = (h, w)

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n world directions (n, 3) float64 and their solid-angle pdf (n,) float64."""
        h, w = self._shape
        u = rng.random((n, 3))
        pix = np.minimum(np.searchsorted(self._cdf, u[:, 0], side="right"), h * w - 1)
        row, col = np.divmod(pix, w)
        z0 = np.cos(math.pi * row / h)
        z1 = np.cos(math.pi * (row + 1) / h)
        cos_t = z0 + (z1 - z0) * u[:, 1]
        sin_t = np.sqrt(np.clip(1.0 - cos_t * cos_t, 0.0, None))
        phi = 2.0 * math.pi * (col + u[:, 2]) / w
        local = np.stack([sin_t * np.sin(phi), cos_t, -sin_t * np.cos(phi)], axis=1)
        return local @ self.env.rotation.T, self._density[pix]

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        """(n,) float64 solid-angle pdf of world ``directions`` (n, 3)."""
        h, w = self._shape
        uv = sh.equirect_uv(np.asarray(directions, np.float64) @ self.env.rotation)
        col = np.minimum((uv[:, 0] * w).astype(np.int64), w - 1)
        row = np.minimum((uv[:, 1] * h).astype(np.int64), h - 1)
        return self._density[row * w + col]


def light_sh(light: Light, bands: int) -> np.ndarray:
    """(L², 3) float64 SH coefficients of a directional light as distant radiance: a delta
    of irradiance ``color · intensity`` arriving from ``−direction``, i.e.
    ``c = color · I · Y(−d)`` (band-limited, so it rings and blurs: the classic PRT
    limitation the comparison shows)."""
    if light.type != "directional":
        raise LightFileError(f"light {light.name or light.type}: only directional lights "
                             f"are distant; SH-PRT cannot take a {light.type} light")
    y = sh.basis(-light_axis(light)[None, :], bands)[0]
    return y[:, None] * (np.asarray(light.color, np.float64) * float(light.intensity))[None, :]


def constant_environment(radiance: np.ndarray, height: int = 8) -> Environment:
    """A uniform environment of RGB ``radiance`` (3,) (an ambient term)."""
    img = np.broadcast_to(np.asarray(radiance, np.float64), (height, 2 * height, 3)).copy()
    return Environment(img, name="constant")


def sky_environment(sun_direction: np.ndarray, height: int = 64, *,
                    zenith: tuple[float, float, float] = (0.25, 0.45, 0.9),
                    horizon: tuple[float, float, float] = (0.9, 0.95, 1.0),
                    ground: tuple[float, float, float] = (0.2, 0.18, 0.15),
                    glow: float = 4.0) -> Environment:
    """A smooth analytic sky (y up): a zenith–horizon gradient, a dim ground and a broad
    glow around the sun (``sun_direction`` (3,), toward the sun). Not a physical sky model;
    the sun itself is a separate directional light (see :func:`sky_with_sun`)."""
    dirs, _ = sh.equirect_directions(height, 2 * height)
    up = dirs[..., 1:2]
    t = np.clip(up, 0.0, 1.0) ** 0.5
    sky = (1.0 - t) * np.asarray(horizon) + t * np.asarray(zenith)
    s = np.asarray(sun_direction, np.float64)
    s = s / np.linalg.norm(s)
    cos_sun = np.clip(dirs @ s, -1.0, 1.0)[..., None]
    img = np.where(up > 0, sky * (1.0 + glow * np.exp(8.0 * (cos_sun - 1.0))), ground)
    return Environment(img, name="sky")


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly distributed 3×3 rotation (QR of a Gaussian matrix, sign-fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))[None, :]
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def rotated_family(env: Environment, count: int, seed: int) -> tuple[Environment, ...]:
    """``count`` copies of ``env`` turned about the world up axis (+y) by seeded random
    angles (a rotating environment, as the runtime turns it)."""
    rng = np.random.default_rng(seed)
    return tuple(env.rotated(rotation_about_y(a)) for a in rng.uniform(0.0, 360.0, count))


def sky_with_sun(rng: np.random.Generator, *, sun_lux: float = 3.0, height: int = 64
                 ) -> tuple[Environment, Light]:
    """A sky with a random sun above the horizon: (sky environment, sun directional light)."""
    phi = rng.uniform(0.0, 2.0 * math.pi)
    elev = rng.uniform(math.radians(10.0), math.radians(80.0))
    to_sun = np.array([math.cos(elev) * math.sin(phi), math.sin(elev),
                       -math.cos(elev) * math.cos(phi)])
    sun = Light(type="directional", color=np.array([1.0, 0.95, 0.85]), intensity=sun_lux,
                direction=-to_sun, name="sun")
    return sky_environment(to_sun, height), sun


def directional_with_ambient(rng: np.random.Generator, *, lux: tuple[float, float] = (1.0, 4.0),
                             ambient: tuple[float, float] = (0.02, 0.2)
                             ) -> tuple[Environment, Light]:
    """A random directional light (uniform direction, log-uniform lux) plus a uniform
    ambient environment (uniform radiance in ``ambient``)."""
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    e = math.exp(rng.uniform(math.log(lux[0]), math.log(lux[1])))
    light = Light(type="directional", color=np.ones(3), intensity=e, direction=d,
                  name="directional")
    return constant_environment(np.full(3, rng.uniform(*ambient))), light


def rotation_about_y(degrees: float) -> np.ndarray:
    """(3, 3) rotation by ``degrees`` about world up (+y), right-handed."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass(frozen=True, eq=False)
class DistantLighting:
    """What a distant-light file holds: an optional environment and directional lights."""

    environment: Environment | None
    lights: tuple[Light, ...]

    def sh_coefficients(self, bands: int) -> np.ndarray:
        """(L², 3) float64 SH of all of it (environment projected, lights as deltas)."""
        out = np.zeros((bands * bands, 3))
        if self.environment is not None:
            out += self.environment.sh_coefficients(bands)
        for light in self.lights:
            out += light_sh(light, bands)
        return out


def load_distant_lighting(path: str | Path) -> DistantLighting:
    """A light file for distant lighting (docs/lights.md, "Environment maps"): a light file
    of directional lights, or an object with ``"environment": {"file": F, "rotation_y_deg":
    a, "scale": s}`` (F relative to the light file; a about +y; both optional) and optionally
    ``"lights": [...]`` (directional). Errors name the file and the key."""
    from prtcore.core.jsonfile import read_json
    from prtcore.emitters.lightfile import light_from_dict, load_light_file

    file = str(path)
    data = read_json(path, lambda what: LightFileError(f"{file}: {what}"))
    if not (isinstance(data, dict) and "environment" in data):
        lights = load_light_file(path)
        env = None
    else:
        unknown = sorted(set(data) - {"environment", "lights"})
        if unknown:
            raise LightFileError(f"{file}: {unknown[0]}: unknown key")
        e = data["environment"]
        if not isinstance(e, dict) or not isinstance(e.get("file"), str):
            raise LightFileError(f"{file}: environment: expected {{\"file\": \"map.exr\", "
                                 f"...}}")
        bad = sorted(set(e) - {"file", "rotation_y_deg", "scale"})
        if bad:
            raise LightFileError(f"{file}: environment.{bad[0]}: unknown key")
        nums = {}
        for key, default in (("rotation_y_deg", 0.0), ("scale", 1.0)):
            v = e.get(key, default)
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
                raise LightFileError(f"{file}: environment.{key}: expected a number, got {v!r}")
            nums[key] = float(v)
        if nums["scale"] < 0:
            raise LightFileError(f"{file}: environment.scale: must be ≥ 0")
        env = load_environment(Path(file).parent / e["file"],
                               rotation=rotation_about_y(nums["rotation_y_deg"]),
                               scale=nums["scale"])
        raw = data.get("lights", [])
        if not isinstance(raw, list):
            raise LightFileError(f"{file}: lights: expected a list of lights")
        lights = tuple(light_from_dict(x, f"lights[{i}]", file) for i, x in enumerate(raw))
    for i, light in enumerate(lights):
        if light.type != "directional":
            raise LightFileError(f"{file}: lights[{i}].type: distant lighting takes "
                                 f"directional lights only, got {light.type!r}")
    return DistantLighting(env, lights)
