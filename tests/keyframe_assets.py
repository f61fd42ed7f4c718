"""Small animated glTF assets for the keyframe tests (built with :class:`GltfBuilder`).

:func:`bending_column_asset`: a grey floor, a red square column skinned to two joints
(the upper joint bends the column by up to 70° about z: linear blend skinning) and a
white wall panel whose node slides along x (node TRS animation) — so that the indirect
light on the floor and column changes with the pose. One animation "bend", 1 s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hostile_assets import GltfBuilder
from scipy.spatial.transform import Rotation


def _quads(corners: list[np.ndarray], outward: list[np.ndarray]):
    """Flat-shaded quads (4 corners each) wound counter-clockwise seen from ``outward``:
    positions (4q, 3), normals (4q, 3), faces (2q, 3)."""
    pos, nrm, faces = [], [], []
    for q, (c, out) in enumerate(zip(corners, outward, strict=True)):
        c = np.asarray(c, float)
        n = np.cross(c[1] - c[0], c[2] - c[0])
        if np.dot(n, out) < 0:
            c = c[[0, 3, 2, 1]]
        pos.append(c)
        nrm.append(np.repeat(np.asarray(out, float)[None] / np.linalg.norm(out), 4, 0))
        faces += [[4 * q, 4 * q + 1, 4 * q + 2], [4 * q, 4 * q + 2, 4 * q + 3]]
    return np.concatenate(pos), np.concatenate(nrm), np.array(faces)


def column_geometry(rings: int = 8, half: float = 0.15, y0: float = 0.02, y1: float = 0.95):
    """The column's four sides as flat quads per ring: positions, normals, faces, and
    per-vertex (joints (v, 4), weights (v, 4)): joint 1 takes over between y 0.35 and 0.65."""
    ys = np.linspace(y0, y1, rings + 1)
    up = np.array([0.0, 1.0, 0.0])
    corners, outward = [], []
    for out in np.eye(3)[[0, 0, 2, 2]] * np.array([1, -1, 1, -1])[:, None]:
        side = np.cross(out, up) * half  # the side's two vertical edges: out·half ± side
        e0, e1 = out * half + side, out * half - side
        for i in range(rings):
            lo, hi = ys[i] * up, ys[i + 1] * up
            corners.append([e0 + lo, e1 + lo, e1 + hi, e0 + hi])
            outward.append(out)
    pos, nrm, faces = _quads(corners, outward)
    w1 = np.clip((pos[:, 1] - 0.35) / 0.3, 0.0, 1.0)
    weights = np.zeros((len(pos), 4))
    weights[:, 0], weights[:, 1] = 1.0 - w1, w1
    joints = np.zeros((len(pos), 4), np.uint16)
    joints[:, 1] = 1
    return pos, nrm, faces, joints, weights


def bending_column_asset(path: Path, bend_degrees: float = 70.0, slide: float = 0.45) -> Path:
    """Write the asset (see module doc) to ``path`` and return it: the column bends by
    ``bend_degrees`` and the wall slides by ``slide`` metres towards it over the second."""
    b = GltfBuilder()
    grey = b.material((0.7, 0.7, 0.7, 1.0))
    red = b.material((0.8, 0.25, 0.2, 1.0))
    white = b.material((0.9, 0.9, 0.9, 1.0))
    fp, fn, ff = _quads([[[-1, 0, -1], [-1, 0, 1], [1, 0, 1], [1, 0, -1]]], [[0, 1, 0]])
    b.node(b.mesh(fp, ff, normals=fn, material=grey), name="floor")
    wp, wn, wf = _quads([[[0, 0, -0.8], [0, 0, 0.8], [0, 1.2, 0.8], [0, 1.2, -0.8]]],
                        [[1, 0, 0]])
    wall = b.node(b.mesh(wp, wf, normals=wn, material=white), name="wall",
                  translation=[-0.8, 0.0, 0.0])
    cp, cn, cf, cj, cw = column_geometry()
    mesh = b.mesh(cp, cf, normals=cn, joints=cj, weights=cw, material=red)
    j1 = b.node(root=False, name="upper", translation=[0.0, 0.5, 0.0])
    j0 = b.node(children=[j1], name="root-joint")
    ibm = np.stack([np.eye(4), np.eye(4)])
    ibm[1, 1, 3] = -0.5
    b.doc["skins"] = [{"joints": [j0, j1], "inverseBindMatrices": b.accessor(ibm),
                       "skeleton": j0}]
    col = b.node(mesh, name="column")
    b.doc["nodes"][col]["skin"] = 0
    times = np.array([0.0, 0.5, 1.0])
    quats = Rotation.from_euler("z", np.array([[0.0], [0.5], [1.0]]) * bend_degrees,
                                degrees=True).as_quat()
    slide = np.array([[-0.8, 0, 0], [-0.8 + 0.5 * slide, 0, 0], [-0.8 + slide, 0, 0]])
    b.doc["animations"] = [{"name": "bend", "channels": [
        {"sampler": 0, "target": {"node": j1, "path": "rotation"}},
        {"sampler": 1, "target": {"node": wall, "path": "translation"}},
    ], "samplers": [
        {"input": b.accessor(times), "output": b.accessor(quats)},
        {"input": b.accessor(times), "output": b.accessor(slide)},
    ]}]
    return b.write_glb(path)
