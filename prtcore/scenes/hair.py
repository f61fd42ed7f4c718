"""Procedural test hair (issue 16): a hairball and a head (a sphere) with straight or curly
hair. Every asset is a pure function of its arguments and ``seed``.

* :func:`hairball` — ``strands`` smooth random curves wandering inside a ball of radius
  ``radius`` (the paper's HAIRBALL has 140k strands; the tests use 10k and fewer);
* :func:`head_hair` — strands rooted on the upper part of a sphere of radius ``radius``
  centred at the origin, growing out along the normal then falling under gravity, kept
  outside the sphere; ``style = "curly"`` winds them in helices about their path;
* :func:`head_mesh` / :func:`write_head` — the matching sphere as a glTF binary, to bake
  hair and mesh together.

Units are metres, +Y up. Diameters are a little thicker than real hair (0.2 mm, real
hair is 0.05–0.1 mm) so that small test assets have a hair volume of useful optical depth.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import trimesh

from prtcore.core.hair import Hair
from prtcore.core.scene import Light
from prtcore.scenes.parts import material_scene, write_glb

HAIR_COLOR = (0.8, 0.6, 0.4)
SKIN_COLOR = (0.7, 0.5, 0.4)
DIAMETER = 2e-4


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _assemble(paths: np.ndarray, rng: np.random.Generator, color, diameter: float,
              name: str, color_jitter: float) -> Hair:
    """(s, n, 3) paths → Hair with per-strand colour jittered by ±``color_jitter``
    (relative) and a diameter tapering to 60 % at the tip."""
    s, n, _ = paths.shape
    scale = 1.0 + color_jitter * (2 * rng.random((s, 1)) - 1)
    col = np.clip(np.asarray(color, float)[None, :] * scale, 0.0, 1.0)
    taper = diameter * np.linspace(1.0, 0.6, n)
    return Hair(offsets=np.arange(s + 1, dtype=np.int64) * n,
                points=paths.reshape(-1, 3).astype(np.float64),
                thickness=np.tile(taper, s), color=np.repeat(col, n, axis=0), name=name)


def hairball(strands: int = 10_000, segments: int = 16, radius: float = 0.1,
             length: float = 0.15, seed: int = 0, diameter: float = DIAMETER,
             color=HAIR_COLOR) -> Hair:
    """A tangle of ``strands`` smooth random curves of ``segments`` segments and arc length
    ``length`` inside the ball of radius ``radius`` about the origin."""
    rng = np.random.default_rng(seed)
    start = _unit(rng.normal(size=(strands, 3))) * radius * np.cbrt(rng.random((strands, 1)))
    d = _unit(rng.normal(size=(strands, 3)))
    step = length / segments
    paths = np.empty((strands, segments + 1, 3))
    paths[:, 0] = p = start
    for k in range(1, segments + 1):
        d = _unit(d + 0.5 * rng.normal(size=(strands, 3)))
        outward = np.linalg.norm(p + step * d, axis=1) > radius
        # turn back toward the centre where the next step would leave the ball
        d[outward] = _unit(d[outward] - 1.5 * _unit(p[outward]))
        p = p + step * d
        paths[:, k] = p
    return _assemble(paths, rng, color, diameter, f"hairball-{strands}", 0.1)


def head_hair(strands: int = 10_000, style: str = "straight", segments: int = 24,
              radius: float = 0.1, length: float = 0.18, seed: int = 0,
              diameter: float = DIAMETER, color=HAIR_COLOR) -> Hair:
    """``strands`` strands rooted on the sphere's cap (y > −0.2 r), straight or curly."""
    if style not in ("straight", "curly"):
        raise ValueError(f"style must be 'straight' or 'curly', not {style!r}")
    rng = np.random.default_rng(seed)
    roots = _unit(rng.normal(size=(strands * 3, 3)))
    roots = roots[roots[:, 1] > -0.2][:strands]
    while len(roots) < strands:  # vanishingly rare top-up; keeps the count exact
        more = _unit(rng.normal(size=(strands, 3)))
        roots = np.concatenate([roots, more[more[:, 1] > -0.2]])[:strands]
    step = length / segments
    lift = 1.0 + 0.02 * rng.random((strands, 1))  # layers: roots a little above the scalp
    p = roots * radius * lift
    d = roots.copy()
    gravity = np.array([0.0, -1.0, 0.0])
    paths = np.empty((strands, segments + 1, 3))
    paths[:, 0] = p
    for k in range(1, segments + 1):
        d = _unit(d + 0.35 * gravity + 0.1 * rng.normal(size=(strands, 3)))
        p = p + step * d
        r = np.linalg.norm(p, axis=1, keepdims=True)
        p = np.where(r < radius * lift, p / r * radius * lift, p)  # stay off the scalp
        paths[:, k] = p
    if style == "curly":
        tangent = _unit(np.gradient(paths, axis=1))
        a = _unit(np.cross(tangent, np.array([0.3, 0.2, 0.9])))
        b = np.cross(tangent, a)
        turns = 2.5 + rng.random((strands, 1))
        phase = 2 * np.pi * rng.random((strands, 1))
        ang = phase + 2 * np.pi * turns * np.linspace(0, 1, segments + 1)[None, :]
        amp = 0.012 * np.sqrt(np.linspace(0.0, 1.0, segments + 1))[None, :, None]
        paths = paths + amp * (np.cos(ang)[..., None] * a + np.sin(ang)[..., None] * b)
        r = np.linalg.norm(paths, axis=2, keepdims=True)
        paths = np.where(r < radius, paths / r * radius * 1.001, paths)
    return _assemble(paths, rng, color, diameter, f"head-{style}-{strands}", 0.1)


def head_mesh(radius: float = 0.1, subdivisions: int = 3) -> trimesh.Scene:
    """The head: an icosphere of ``radius`` at the origin, one skin-coloured material."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return material_scene({"head": sphere}, {"head": SKIN_COLOR})


def write_head(path: str | Path, radius: float = 0.1, subdivisions: int = 3) -> Path:
    """Write :func:`head_mesh` as a ``.glb``."""
    return write_glb(head_mesh(radius, subdivisions), path)


def tangle(strands: int = 1000, seed: int = 0) -> Hair:
    """A small dense hairball (radius 3 cm, 6 cm strands of 12 segments, 0.3 mm thick):
    most rays leaving a fibre hit another, so multiple scattering matters — the accuracy
    checks of the fibre transport (tests/test_reference_fibres.py,
    benchmarks/hair_accuracy.py) use it with :func:`tangle_lights`."""
    return hairball(strands=strands, segments=12, radius=0.03, length=0.06, seed=seed,
                    diameter=3e-4)


def tangle_lights() -> list[Light]:
    """A sun from straight above and a point light to the side of :func:`tangle`."""
    return [Light(type="directional", color=np.ones(3), intensity=3.0,
                  direction=np.array([0.0, -1.0, 0.0])),
            Light(type="point", color=np.ones(3), intensity=0.05,
                  position=np.array([0.08, 0.05, 0.0]))]


def hairball_lights() -> list[Light]:
    """:func:`tangle_lights` for the 10 cm :func:`hairball`: the same sun, and the point
    light to the side moved outside the ball (3.75× as far, 3.75² its intensity) — the
    accuracy checks on the bake's own test asset (benchmarks/hair_accuracy.py,
    benchmarks/hair_chiang_accuracy.py ``--scene hairball``)."""
    sun, point = tangle_lights()
    scale = 0.1 / 0.03 * 1.125
    return [sun, dataclasses.replace(point, position=point.position * scale,
                                     intensity=point.intensity * scale ** 2)]


def head_lights() -> list[Light]:
    """A sun from above, behind and to the side, and a point light to the front right of
    :func:`head_mesh` with :func:`head_hair` (the hair + mesh accuracy checks,
    tests/test_hair_mesh.py, benchmarks/hair_mesh_accuracy.py)."""
    sun = np.array([-0.3, -1.0, -0.4])
    return [Light(type="directional", color=np.ones(3), intensity=3.0,
                  direction=sun / np.linalg.norm(sun)),
            Light(type="point", color=np.ones(3), intensity=0.3,
                  position=np.array([0.25, 0.05, 0.15]))]
