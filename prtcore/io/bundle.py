"""The bundle (docs/bundle.md): what an engine loads, described entirely by manifest.json.

Written atomically: everything goes to a temporary sibling directory that is renamed into
place at the end, so a failed bake leaves no partial bundle (and an existing bundle is only
replaced, with ``force``, once the new one is complete).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prtcore import __version__
from prtcore.core.errors import BundleError, PrtError
from prtcore.core.mlp import Mlp
from prtcore.io.imageio import read_image, write_exr

SCHEMA = "prtcore.bundle"
VERSION = 1
PLANES_PER_FILE = 4


@dataclass(frozen=True)
class RuntimeData:
    """What the runtime needs, as loaded from a bundle.

    planes : (h, w, q) float32 basis planes (q = 3 + n_b for mono, 3 + 3·n_b for rgb)
    plane_element : (q,) int32 element index of each plane; plane_channel : (q,) int8,
        0/1/2 for R/G/B, −1 for a plane shared by all channels (mono)
    transfer : (3, n_b, P) or (G, 3, n_b, P) float32; offset : (3, n_b) or (G, 3, n_b)
    gamma : float or None; coverage : (h, w) bool
    cluster_position, cluster_normal, cluster_albedo : (s, 3) float32 (albedo as used by
        transport, i.e. clamped); cluster_owner : (s,) int32; point_count : P
    """

    planes: np.ndarray
    plane_element: np.ndarray
    plane_channel: np.ndarray
    transfer: np.ndarray
    offset: np.ndarray
    gamma: float | None
    coverage: np.ndarray
    cluster_position: np.ndarray
    cluster_normal: np.ndarray
    cluster_albedo: np.ndarray
    cluster_owner: np.ndarray
    point_count: int
    keyframe_times: tuple[float, ...] | None = None
    #: (r, 3P) float32 span of the training direct vectors and the residual above which a
    #: light is out of family (prtcore.runtime.family); None in bundles without them
    direct_span: np.ndarray | None = None
    family_warn_above: float | None = None
    #: fit.transfer "mlp": the learnt residual network (prtcore.core.mlp), None for ridge
    learnt: Mlp | None = None

    @property
    def n_basis(self) -> int:
        """Elements including the mean."""
        return int(self.plane_element.max()) + 1


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def raw_file(path: Path, array: np.ndarray, dtype: str = "<f4") -> dict:
    """Write ``array`` as raw little-endian ``dtype`` to ``path``; returns its manifest
    description {"file", "dtype", "shape"}."""
    a = np.ascontiguousarray(array, dtype=dtype)
    path.write_bytes(a.tobytes())
    return {"file": path.name, "dtype": dtype, "shape": list(a.shape)}


def planes_layout(channels: str, n_b: int) -> tuple[np.ndarray, np.ndarray]:
    """(plane_element, plane_channel) for a basis of n_b elements besides the mean."""
    el = [0, 0, 0]
    ch = [0, 1, 2]
    for i in range(1, n_b + 1):
        if channels == "mono":
            el.append(i)
            ch.append(-1)
        else:
            el += [i, i, i]
            ch += [0, 1, 2]
    return np.asarray(el, np.int32), np.asarray(ch, np.int8)


def basis_planes(mean: np.ndarray, basis: np.ndarray, channels: str) -> np.ndarray:
    """Per-texel planes in layout order: (t, q) float32 from mean (t, 3) and basis
    (t, n_b) mono or (t, n_b, 3) rgb."""
    if channels == "mono":
        return np.concatenate([mean, basis], axis=1).astype(np.float32)
    return np.concatenate([mean, basis.reshape(len(basis), -1)], axis=1).astype(np.float32)


def learnt_files(directory: Path, net: Mlp) -> dict:
    """The learnt transfer's layers as raw little-endian float32 files
    ``transfer_learnt_<j>_weight.bin`` (out, in) and ``..._bias.bin`` (out,); returns
    the manifest's ``transfer.learnt`` section (docs/bundle.md)."""
    layers = [{"weight": raw_file(directory / f"transfer_learnt_{j}_weight.bin", w),
               "bias": raw_file(directory / f"transfer_learnt_{j}_bias.bin", c)}
              for j, (w, c) in enumerate(zip(net.weights, net.biases, strict=True))]
    return {"layers": layers, "activation": "leaky_relu", "slope": net.slope,
            "output": net.output,
            "input": "x'/s flattened channel-major: index c*P + p (zero input when s = 0)",
            "layout": "output index c*(n-1) + i: channel c, element i+1; "
                      "u_c,i += s * output[c*(n-1) + i]"}


def read_learnt(path: Path, section: dict) -> Mlp:
    """The network of a manifest's ``transfer.learnt`` section."""
    if section.get("activation") != "leaky_relu":
        raise BundleError(f"{path}: transfer.learnt activation "
                          f"{section.get('activation')!r}: this prtcore reads 'leaky_relu'")
    try:
        return Mlp(tuple(load_raw(path, layer["weight"]) for layer in section["layers"]),
                   tuple(load_raw(path, layer["bias"]) for layer in section["layers"]),
                   float(section["slope"]), section.get("output", "linear"))
    except ValueError as e:
        raise BundleError(f"{path}: transfer.learnt: {e}") from None


def is_bundle(path: str | Path) -> bool:
    """True when ``path`` is a directory whose manifest.json says it is a prtcore bundle."""
    path = Path(path)
    if path.is_symlink() or not path.is_dir():
        return False
    try:
        m = json.loads((path / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(m, dict) and m.get("schema") == SCHEMA


def check_output(out: str | Path, force: bool = False,
                 inputs: tuple[str | Path, ...] = ()) -> None:
    """Refuse an output path that a bake must not write or replace (nothing is lost).

    Refused always: ``out`` is one of ``inputs`` or a directory holding one. Refused unless
    ``force``: ``out`` exists. Refused even with ``force``: ``out`` is a file, a link or a
    directory that is not a prtcore bundle (:func:`is_bundle`). Raises :class:`PrtError`
    with one line naming the path and the reason.
    """
    out = Path(out)
    where = out.resolve()
    for src in inputs:
        s = Path(src).resolve()
        if s == where or where in s.parents:
            what = "the input" if s == where else "a directory holding the input"
            raise PrtError(f"{out}: is {what} {src}; choose another --out")
    if not (out.exists() or out.is_symlink()):
        return
    if not force:
        raise PrtError(f"{out}: already exists (use --force to replace it)")
    if out.is_symlink() or not out.is_dir():
        raise PrtError(f"{out}: is a file, not a prtcore bundle; refusing to replace it")
    if not is_bundle(out):
        raise PrtError(f"{out}: is a directory but not a prtcore bundle (no manifest.json "
                       f"with schema {SCHEMA!r}); refusing to replace it")


def write_bundle(out: Path, writer: Callable[[Path], dict[str, Any]], force: bool = False,
                 exclude: tuple[str, ...] = (), inputs: tuple[str | Path, ...] = ()) -> Path:
    """Run ``writer(tmpdir) -> manifest`` and move the result to ``out`` atomically.

    ``writer`` writes its files into the temporary directory and returns the manifest
    (without checksums); this function adds per-file sha256 and sizes (files named in
    ``exclude`` — run reports — are left out), writes
    manifest.json and renames the directory into place.
    """
    out = Path(out)
    check_output(out, force, inputs)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    try:
        manifest = writer(tmp)
        files = {}
        for p in sorted(tmp.iterdir()):
            if p.is_file() and p.name not in exclude:
                files[p.name] = {"bytes": p.stat().st_size, "sha256": sha256_file(p)}
        manifest["checksums"] = files
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it 0700
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2, sort_keys=False)
                                           + "\n", encoding="utf-8")
        if out.exists():
            check_output(out, force, inputs)  # still a bundle now that the new one is done
            old = out.with_name(f".{out.name}.old")
            if old.exists():
                shutil.rmtree(old)
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def write_basis_files(directory: Path, planes_image: np.ndarray, dtype: str,
                      prefix: str = "basis") -> list[str]:
    """Pack (h, w, q) planes into {prefix}_XX.exr files, 4 planes per RGBA file."""
    h, w, q = planes_image.shape
    names = []
    for f in range(0, q, PLANES_PER_FILE):
        chunk = np.zeros((h, w, PLANES_PER_FILE), np.float32)
        part = planes_image[:, :, f:f + PLANES_PER_FILE]
        chunk[:, :, :part.shape[2]] = part
        name = f"{prefix}_{f // PLANES_PER_FILE:02d}.exr"
        write_exr(directory / name, chunk, dtype=dtype)
        names.append(name)
    return names


def points_files(directory: Path, points, cluster_albedo: np.ndarray) -> dict:
    """Measurement points and their supersample clusters as raw little-endian files.

    cluster_albedo : (s, 3) the albedo used by transport (clamped), so that the engine's
    shading reproduces the training data.
    """
    albedo_pts = points.average_clusters(cluster_albedo) if len(cluster_albedo) else \
        points.albedo
    cols = ["px", "py", "pz", "nx", "ny", "nz", "albedo_r", "albedo_g", "albedo_b",
            "bary0", "bary1", "bary2"]
    pts = np.concatenate([points.position, points.normal, albedo_pts, points.barycentric], 1)
    cl = np.concatenate([points.cluster_position, points.cluster_normal, cluster_albedo,
                         points.cluster_barycentric], 1)
    return {
        "count": int(points.count),
        "placement": points.placement,
        "columns": cols,
        "points": raw_file(directory / "points.bin", pts, "<f4"),
        "points_triangle": raw_file(directory / "points_triangle.bin", points.triangle, "<i4"),
        "clusters": raw_file(directory / "clusters.bin", cl, "<f4"),
        "clusters_triangle": raw_file(directory / "clusters_triangle.bin",
                                  points.cluster_triangle, "<i4"),
        "clusters_owner": raw_file(directory / "clusters_owner.bin", points.cluster_owner, "<i4"),
    }


# ---------------------------------------------------------------------------------------
# Reading


def read_manifest(path: Path) -> dict:
    path = Path(path)
    mpath = path / "manifest.json"
    if not mpath.is_file():
        raise BundleError(f"{path}: not a bundle (no manifest.json)")
    try:
        m = json.loads(mpath.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise BundleError(f"{mpath}: invalid JSON at line {e.lineno}: {e.msg}") from None
    if m.get("schema") != SCHEMA:
        raise BundleError(f"{mpath}: schema is {m.get('schema')!r}, expected {SCHEMA!r}")
    if m.get("version") != VERSION:
        raise BundleError(f"{mpath}: bundle version {m.get('version')!r} is not supported "
                          f"(this prtcore reads version {VERSION})")
    return m


def verify_bundle(path: Path, manifest: dict | None = None) -> None:
    """Check every file listed in the manifest exists with its recorded sha256."""
    path = Path(path)
    manifest = manifest or read_manifest(path)
    for name, info in manifest.get("checksums", {}).items():
        p = path / name
        if not p.is_file():
            raise BundleError(f"{path}: {name} listed in manifest.json is missing")
        if p.stat().st_size != info["bytes"] or sha256_file(p) != info["sha256"]:
            raise BundleError(f"{path}: {name} does not match its manifest checksum")


def load_raw(path: Path, desc: dict) -> np.ndarray:
    """The array a manifest's raw-file description (:func:`raw_file`) names, in bundle
    ``path``; a missing file or a size that disagrees with the shape is a BundleError."""
    p = path / desc["file"]
    if not p.is_file():
        raise BundleError(f"{path}: {desc['file']} is missing")
    a = np.fromfile(p, dtype=np.dtype(desc["dtype"]))
    shape = tuple(desc["shape"])
    if a.size != int(np.prod(shape)):
        raise BundleError(f"{path}: {desc['file']} holds {a.size} values, manifest says "
                          f"shape {list(shape)}")
    return a.reshape(shape)


def load_runtime(path: Path, manifest: dict | None = None) -> RuntimeData:
    """Everything the runtime needs, from the bundle files as the manifest describes them."""
    path = Path(path)
    m = manifest or read_manifest(path)
    if m.get("method", "data_driven") != "data_driven":
        raise BundleError(f"{path}: method {m['method']!r} has no data-driven runtime data")
    basis = m["basis"]
    imgs = [read_image(path / f) for f in basis["files"]]
    planes = np.concatenate(imgs, axis=2)[:, :, :basis["planes"]]
    el = np.asarray(basis["plane_element"], np.int32)
    ch = np.asarray(basis["plane_channel"], np.int8)
    cov = read_image(path / m["atlas"]["coverage"])[:, :, 0] > 0.5
    pts = m["points"]
    clusters = load_raw(path, pts["clusters"])
    return RuntimeData(
        planes=planes, plane_element=el, plane_channel=ch,
        transfer=load_raw(path, m["transfer"]["matrix"]),
        offset=load_raw(path, m["transfer"]["offset"]),
        gamma=m["fit"]["gamma"], coverage=cov,
        cluster_position=clusters[:, 0:3], cluster_normal=clusters[:, 3:6],
        cluster_albedo=clusters[:, 6:9],
        cluster_owner=load_raw(path, pts["clusters_owner"]).astype(np.int64),
        point_count=int(pts["count"]),
        keyframe_times=None if not m.get("keyframes") else tuple(m["keyframes"]["times"]),
        direct_span=load_raw(path, m["family"]["span"]) if m.get("family") else None,
        family_warn_above=m["family"]["warn_above"] if m.get("family") else None,
        learnt=read_learnt(path, m["transfer"]["learnt"]) if m["transfer"].get("learnt")
        else None,
    )


def atlas_section(texels, padding: int) -> dict:
    """The manifest's ``atlas`` of a lightmap (a
    :class:`~prtcore.receivers.texels.TexelSpace` sampled through TEXCOORD_1)."""
    from prtcore.io.imageio import EXR_ROW_ORDER

    return {"width": texels.width, "height": texels.height, "padding": padding,
            "uv": "TEXCOORD_1",
            "texel_center": "((x+0.5)/W, (y+0.5)/H), y from the top row",
            "covered_texels": texels.count, "coverage": "coverage.exr",
            # readers that store scanlines bottom-up (three.js EXRLoader) sample at
            # (u, 1 - v); docs/bundle.md
            "exr_row_order": EXR_ROW_ORDER}


def is_hair_mesh(manifest: dict) -> bool:
    """A hair + mesh bundle (docs/hair.md): the atlas is the mesh's lightmap and the
    manifest's ``strands`` names a second set of basis files, the strand texture's."""
    return bool((manifest.get("strands") or {}).get("basis_files"))


def strand_runtime(path: Path, manifest: dict, data: RuntimeData) -> RuntimeData:
    """A hair + mesh bundle's runtime data for its strand texture: ``data``
    (:func:`load_runtime`) with the planes and coverage of ``strands.basis_files`` and
    ``strands.coverage`` (the same planes, stored in the strand texture)."""
    st = manifest["strands"]
    imgs = [read_image(Path(path) / f) for f in st["basis_files"]]
    planes = np.concatenate(imgs, axis=2)[:, :, :data.planes.shape[2]]
    cov = read_image(Path(path) / st["coverage"])[:, :, 0] > 0.5
    return dataclasses.replace(data, planes=planes, coverage=cov)


def load_keyframe(path: Path, manifest: dict, k: int) -> dict[str, np.ndarray]:
    """Keyframe k's posed arrays from a keyframe bundle: "vertices" (V', 6) positions +
    normals in asset.glb vertex order, "clusters" (s, 6), "points" (P, 6) float32."""
    kf = manifest.get("keyframes") or {}
    n = len(kf.get("times", ()))
    if not 0 <= k < n:
        raise BundleError(f"{path}: keyframe {k} out of range (the bundle has {n})")
    return {name: load_raw(Path(path), kf[name])[k]
            for name in ("vertices", "clusters", "points")}


def manifest_base(**fields: Any) -> dict:
    return {"schema": SCHEMA, "version": VERSION, "generator": f"prtcore {__version__}",
            **fields}
