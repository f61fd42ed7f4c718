"""Translucent test scenes (issue 15, docs/subsurface.md): closed meshes filled with a
scattering medium behind a Lambertian-transmitting boundary, written as .glb with
``KHR_materials_volume``, ``KHR_materials_volume_scatter`` and
``KHR_materials_diffuse_transmission`` on their translucent materials.

* :func:`write_translucent_sphere` — a sphere over a grey floor;
* :func:`write_translucent_fin` — a ≥ 20k-triangle blob with a thin fin that light shines
  through, over a grey floor.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import trimesh

from prtcore.scenes.parts import material_scene, quad, write_glb


def add_translucency(glb: bytes, media: dict[str, dict]) -> bytes:
    """The GLB with the glTF extensions of a translucent material added to the materials
    named in ``media``: name → ``{"multiscatter": [r, g, b], "mean_free_path": [r, g, b]
    (world units), "anisotropy": g, "transmission": t, "transmission_color": [r, g, b]}``
    (attenuation colour e^(−d/ℓ) over d = the shortest mean free path)."""
    magic, version, _ = struct.unpack_from("<III", glb, 0)
    jlen, jtype = struct.unpack_from("<II", glb, 12)
    doc = json.loads(glb[20:20 + jlen])
    rest = glb[20 + jlen:]
    used = set(doc.get("extensionsUsed", []))
    for mat in doc.get("materials", []):
        m = media.get(mat.get("name"))
        if m is None:
            continue
        mfp = np.broadcast_to(np.asarray(m["mean_free_path"], np.float64), (3,))
        d = float(mfp.min())
        mat.setdefault("extensions", {}).update({
            "KHR_materials_volume": {
                "thicknessFactor": 1.0, "attenuationDistance": d,
                "attenuationColor": [float(c) for c in np.exp(-d / mfp)]},
            "KHR_materials_volume_scatter": {
                "multiscatterColorFactor": [float(c) for c in np.broadcast_to(
                    np.asarray(m["multiscatter"], np.float64), (3,))],
                "scatterAnisotropy": float(m.get("anisotropy", 0.0))},
            "KHR_materials_diffuse_transmission": {
                "diffuseTransmissionFactor": float(m.get("transmission", 0.5)),
                "diffuseTransmissionColorFactor": [float(c) for c in
                                                   m.get("transmission_color", [1, 1, 1])]},
        })
        used |= set(mat["extensions"])
    doc["extensionsUsed"] = sorted(used)
    body = json.dumps(doc, separators=(",", ":")).encode()
    body += b" " * (-len(body) % 4)
    out = struct.pack("<II", len(body), jtype) + body + rest
    return struct.pack("<III", magic, version, 12 + len(out)) + out


def _floor(size: float, y: float, subdiv: int = 8) -> trimesh.Trimesh:
    h = size / 2
    return quad(np.array([[-h, y, h], [h, y, h], [h, y, -h], [-h, y, -h]]), subdiv)


def write_translucent_sphere(path: str | Path, *, mean_free_path=0.1, multiscatter=0.8,
                             anisotropy: float = 0.0, subdivisions: int = 3,
                             floor: bool = True) -> Path:
    """A unit sphere (material "skin", translucent) centred at the origin, over a grey
    floor (material "floor", albedo 0.5) at y = −1.01 when ``floor``."""
    parts = {"skin": trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)}
    albedo = {"skin": (0.9, 0.9, 0.9)}
    if floor:
        parts["floor"] = _floor(6.0, -1.01)
        albedo["floor"] = (0.5, 0.5, 0.5)
    path = write_glb(material_scene(parts, albedo), path)
    media = {"skin": {"multiscatter": multiscatter, "mean_free_path": mean_free_path,
                      "anisotropy": anisotropy, "transmission": 0.5,
                      "transmission_color": [0.9, 0.9, 0.9]}}
    path.write_bytes(add_translucency(path.read_bytes(), media))
    return path


def fin_blob(subdivisions: int = 6) -> trimesh.Trimesh:
    """A closed blob with a thin fin: an icosphere (≈ 20·4^s triangles) whose upper part
    is squeezed into a fin 0.1 thick at its top, with a lumpy body. Deterministic."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = mesh.vertices.copy()
    y = v[:, 1]
    # lumps on the body (fixed low-frequency pattern)
    lump = 1.0 + 0.08 * np.sin(3 * v[:, 0] + 1.0) * np.cos(2 * v[:, 2] - 0.5)
    v *= lump[:, None]
    # the fin: above y = 0.2 the z extent shrinks to 0.05 at the top, and it rises
    up = np.clip((y - 0.2) / 0.8, 0.0, 1.0)
    v[:, 2] *= 1.0 - 0.95 * up ** 0.7
    v[:, 1] += 0.6 * up ** 2
    mesh = trimesh.Trimesh(v, mesh.faces, process=False)
    return mesh


def write_translucent_fin(path: str | Path, *, mean_free_path=0.08,
                          multiscatter=(0.85, 0.6, 0.45), subdivisions: int = 5) -> Path:
    """The fin blob (material "skin", translucent, 20 480 triangles at 5 subdivisions) over
    a grey floor ("floor", albedo 0.5) just below it."""
    blob = fin_blob(subdivisions)
    y0 = float(blob.vertices[:, 1].min()) - 0.01
    parts = {"skin": blob, "floor": _floor(6.0, y0)}
    albedo = {"skin": (0.9, 0.8, 0.7), "floor": (0.5, 0.5, 0.5)}
    path = write_glb(material_scene(parts, albedo), path)
    media = {"skin": {"multiscatter": multiscatter, "mean_free_path": mean_free_path,
                      "transmission": 0.5, "transmission_color": [0.9, 0.8, 0.7]}}
    path.write_bytes(add_translucency(path.read_bytes(), media))
    return path
