"""Keyframe sets (paper 5.4): pose an animated asset at chosen times.

An animated asset is baked at F keyframes of one animation. The lightmap UV layout is the
rest pose's (TEXCOORD_1 never moves); what follows the pose is everything with a world
position: the scene's vertices, the texels (triangle + barycentrics → position, normals,
footprint) and the measurement points (triangle + barycentrics). One basis is fitted over
all keyframes, with either one transfer matrix for the animation or one per keyframe.

* :func:`keyframe_times` — the F times of the spec (given, or drawn from its seed, one
  per equal sub-interval of the animation);
* :func:`node_matrices` — every node's world matrix at time t (node TRS animation,
  glTF sampler interpolation LINEAR / STEP / CUBICSPLINE, rotations slerped);
* :func:`pose_scene` — vertices by rigid node transforms or linear blend skinning
  (JOINTS_0 / WEIGHTS_0, inverse bind matrices), normals by the inverse-transpose;
* :func:`pose_texels`, :func:`pose_points` — the rest pose's samples on the posed scene;
* :func:`assign_keyframes` — which keyframe each light configuration is drawn with;
* :func:`export_vertex_order` / :func:`bundle_at_time` — per-keyframe vertices in the
  bundle's asset.glb order and the runtime posed at a requested time (nearest keyframe;
  :func:`time_outside_warning` for a time outside the animation).

Morph-target ("weights") channels are not supported (the loader keeps no morph targets).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prtcore.core.errors import PrtError, SpecError
from prtcore.core.progress import StageTimer
from prtcore.core.scene import Animation, AnimationChannel, Light, Scene
from prtcore.core.spec import BakeSpec, TransportSpec
from prtcore.intake.plan import animation_index
from prtcore.intake.points import MeasurementPoints
from prtcore.receivers.texels import TexelSpace


def keyframe_times(animation: Animation, spec: BakeSpec) -> np.ndarray:
    """(F,) float64 keyframe times in seconds, ascending.

    ``keyframes.times`` when given (each must lie within the animation's duration), else
    ``keyframes.count`` times drawn from ``keyframes.seed``, stratified: [0, duration] is
    cut into F equal sub-intervals and each gets one uniform draw, so the keyframes cover
    the whole animation (F independent uniform draws cluster: 0.64, 1.18, 1.22 s of
    1.25 s, nothing near 0).
    """
    k = spec.keyframes
    duration = animation.duration
    if k.times is not None:
        t = np.asarray(k.times, dtype=np.float64)
        bad = t[(t < 0) | (t > duration + 1e-9)]
        if bad.size:
            raise SpecError("keyframes.times", f"time {bad[0]:g} s is outside animation "
                            f"{animation.name!r} (0..{duration:g} s)")
        return np.sort(t)
    rng = np.random.default_rng(k.seed)
    u = rng.uniform(0.0, 1.0, size=k.count)
    # (i + u_i) / F stays in sub-interval i; min() guards the last one against round-off
    return np.minimum((np.arange(k.count) + u) * (duration / k.count), duration)


def assign_keyframes(n: int, count: int, seed: int | Sequence[int]) -> np.ndarray:
    """(n,) int64 keyframe of each of n light configurations: balanced (every keyframe
    gets ⌊n/F⌋ or ⌈n/F⌉), in a seeded random order — the (keyframe, light) pairs."""
    rng = np.random.default_rng(seed)
    return rng.permutation(np.arange(n, dtype=np.int64) % count)


# ---------------------------------------------------------------------------------------
# Animation sampling


def sample_channel(channel: AnimationChannel, t: float) -> np.ndarray:
    """The channel's value at time t (clamped to its time range): (c,) float64.

    LINEAR interpolates translation/scale linearly and rotation by slerp; STEP holds the
    previous key; CUBICSPLINE is the glTF Hermite spline (rotation renormalised).
    """
    times = np.asarray(channel.times, dtype=np.float64)
    vals = np.asarray(channel.values, dtype=np.float64)
    cubic = channel.interpolation == "CUBICSPLINE"
    key = vals[1::3] if cubic else vals  # (k, c) the key values
    if len(times) == 1 or t <= times[0]:
        return _unit(key[0], channel.path)
    if t >= times[-1]:
        return _unit(key[-1], channel.path)
    i = int(np.searchsorted(times, t, side="right") - 1)
    t0, t1 = times[i], times[i + 1]
    dt = t1 - t0
    s = (t - t0) / dt if dt > 0 else 0.0
    if channel.interpolation == "STEP":
        return _unit(key[i], channel.path)
    if cubic:
        p0, m0 = vals[3 * i + 1], vals[3 * i + 2] * dt  # value, out-tangent of key i
        p1, m1 = vals[3 * (i + 1) + 1], vals[3 * (i + 1)] * dt  # value, in-tangent of i+1
        s2, s3 = s * s, s * s * s
        v = ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0
             + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1)
        return _unit(v, channel.path)
    if channel.path == "rotation":
        from scipy.spatial.transform import Rotation, Slerp

        return Slerp([0.0, 1.0], Rotation.from_quat(key[i:i + 2]))([s]).as_quat()[0]
    return (1 - s) * key[i] + s * key[i + 1]


def _unit(v: np.ndarray, path: str) -> np.ndarray:
    if path != "rotation":
        return np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else np.array([0.0, 0.0, 0.0, 1.0])


def node_matrices(scene: Scene, animation: Animation | None, t: float) -> np.ndarray:
    """(N, 4, 4) float64 world_from_node of every node at time t.

    Animated nodes use their rest TRS with the animated components replaced; the others
    keep their rest local matrix (so ``animation=None`` gives the rest pose exactly).
    """
    from prtcore.io.gltf.loader import trs_matrix

    nodes = scene.nodes
    local = [n.matrix.astype(np.float64) for n in nodes]
    if animation is not None:
        trs: dict[int, dict[str, np.ndarray]] = {}
        for ch in animation.channels:
            if ch.path not in ("translation", "rotation", "scale") or not len(ch.times):
                continue
            trs.setdefault(ch.node, {})[ch.path] = sample_channel(ch, t)
        for i, parts in trs.items():
            nd = nodes[i]
            local[i] = trs_matrix(parts.get("translation", nd.translation),
                                  parts.get("rotation", nd.rotation),
                                  parts.get("scale", nd.scale))
    world: list[np.ndarray | None] = [None] * len(nodes)

    def resolve(i: int) -> np.ndarray:
        chain = []
        while i >= 0 and world[i] is None:
            chain.append(i)
            i = nodes[i].parent
        m = np.eye(4) if i < 0 else world[i]
        for j in reversed(chain):
            m = m @ local[j]
            world[j] = m
        return m

    for i in range(len(nodes)):
        resolve(i)
    return np.stack(world) if nodes else np.zeros((0, 4, 4))


# ---------------------------------------------------------------------------------------
# Posing


def pose_scene(scene: Scene, world: np.ndarray) -> Scene:
    """The scene with every instance's vertices placed by node matrices ``world`` (N, 4, 4).

    Rigid instances: world[node]; skinned ones (the node has a skin and the instance keeps
    per-vertex joints): Σ_k w_k · world[joint_k] · inverse_bind_k, weights renormalised,
    zero-weight vertices by world[node] — the loader's rest-pose rule at another time.
    Faces, UVs and materials are unchanged. Raises :class:`PrtError` for a scene without
    instance records (nothing to re-pose from).
    """
    from prtcore.io.gltf.nodes import normal_matrix, normalize_rows

    if not scene.instances:
        raise PrtError(f"{scene.source}: no primitive instances recorded, cannot pose it")
    pos = scene.positions.copy()
    nrm = scene.normals.copy()
    for inst in scene.instances:
        v0, v1 = inst.vertex_start, inst.vertex_start + inst.vertex_count
        if v1 == v0:
            continue
        node = scene.nodes[inst.node]
        op, on = inst.object_positions, inst.object_normals
        if node.skin >= 0 and len(inst.joints) == inst.vertex_count:
            skin = scene.skins[node.skin]
            joint_mats = world[skin.joints] @ skin.inverse_bind  # (j, 4, 4)
            w = inst.weights
            total = w.sum(axis=1, keepdims=True)
            w = np.divide(w, total, out=np.zeros_like(w), where=total > 0)
            m = np.einsum("vk,vkij->vij", w, joint_mats[inst.joints])
            m[total[:, 0] <= 0] = world[inst.node]
            lin = m[:, :3, :3]
            pos[v0:v1] = np.einsum("vij,vj->vi", lin, op) + m[:, :3, 3]
            nrm[v0:v1] = np.einsum("vij,vj->vi", normal_matrix(lin), on)
        else:
            m = world[inst.node]
            pos[v0:v1] = op @ m[:3, :3].T + m[:3, 3]
            nrm[v0:v1] = on @ normal_matrix(m[:3, :3]).T
        nrm[v0:v1] = normalize_rows(nrm[v0:v1])
    return dataclasses.replace(scene, positions=pos, normals=nrm)


def pose_texels(texels: TexelSpace, posed: Scene) -> TexelSpace:
    """The rest pose's texels on the posed scene: same texels, triangles, barycentrics,
    albedo and coverage; positions, shading / geometric normals and footprints recomputed
    (the posed scene must keep the rest pose's faces and TEXCOORD_1)."""
    from prtcore.core.geometry import shading_normals
    from prtcore.receivers.texels import face_frames

    tri = texels.triangle
    position = np.einsum("nk,nkj->nj", texels.barycentric, posed.positions[posed.faces[tri]])
    owners, row = np.unique(tri, return_inverse=True)
    gn, fp = face_frames(posed, owners, texels.width, texels.height)
    gnormal, footprint = gn[row], fp[row]
    normal = shading_normals(posed, tri, texels.barycentric, gnormal)
    return dataclasses.replace(texels, position=position, normal=normal,
                               geometric_normal=gnormal, footprint=footprint)


def pose_points(points: MeasurementPoints, rest: Scene, posed: Scene) -> MeasurementPoints:
    """Measurement points (and their clusters) moved with their triangle + barycentrics.

    "surface" points take the posed surface point and interpolated normal; "hull" points
    (not on the surface) move by the displacement of their closest surface point and keep
    their normal, as the placement documents.
    """
    from prtcore.core.geometry import shading_normals

    def move(p, n, tri, bary):
        at_posed = np.einsum("nk,nkj->nj", bary, posed.positions[posed.faces[tri]])
        if points.placement == "surface":
            return at_posed, shading_normals(posed, tri, bary)
        at_rest = np.einsum("nk,nkj->nj", bary, rest.positions[rest.faces[tri]])
        return p + (at_posed - at_rest), n

    pp, pn = move(points.position, points.normal, points.triangle, points.barycentric)
    cp, cn = move(points.cluster_position, points.cluster_normal, points.cluster_triangle,
                  points.cluster_barycentric)
    return dataclasses.replace(points, position=pp, normal=pn, cluster_position=cp,
                               cluster_normal=cn)


# ---------------------------------------------------------------------------------------
# The keyframe set of a bake


@dataclass(frozen=True)
class KeyframeSet:
    """The keyframes of a bake and which keyframe each light configuration is drawn with.

    animation : index into ``Scene.animations``; name, duration (s) for the record
    times : (F,) float64 seconds, ascending; transfer : "shared" | "per_keyframe"
    train : (K,) int64, holdout : (H,) int64 keyframe of each configuration
    scenes : F posed scenes (the rest scene's faces, UVs, materials);
    points : F posed measurement point sets
    """

    animation: int
    name: str
    duration: float
    times: np.ndarray
    transfer: str
    train: np.ndarray
    holdout: np.ndarray
    scenes: tuple[Scene, ...]
    points: tuple[MeasurementPoints, ...]

    @property
    def count(self) -> int:
        return len(self.times)


def build_keyframes(scene: Scene, points: MeasurementPoints, spec: BakeSpec,
                    n_train: int, n_holdout: int) -> KeyframeSet:
    """Times, (keyframe, light) pairing and posed scenes/points for the spec's animation.

    Raises :class:`SpecError` for a per-keyframe transfer with fewer than 2 training
    configurations per keyframe (each keyframe's regression needs them).
    """
    idx = animation_index(scene, spec)
    if idx is None:
        raise SpecError("keyframes.animation", "not set: nothing to pose")
    anim = scene.animations[idx]
    times = keyframe_times(anim, spec)
    F = len(times)
    k = spec.keyframes
    if k.transfer == "per_keyframe" and n_train < 2 * F:
        raise SpecError("keyframes.count", f"{F} keyframes with transfer per_keyframe need "
                        f"at least {2 * F} training lights (lights.count is {n_train})")
    scenes = tuple(pose_scene(scene, node_matrices(scene, anim, float(t))) for t in times)
    return KeyframeSet(
        animation=idx, name=anim.name, duration=anim.duration, times=times,
        transfer=k.transfer, train=assign_keyframes(n_train, F, [k.seed, 0]),
        holdout=assign_keyframes(n_holdout, F, [k.seed, 1]), scenes=scenes,
        points=tuple(pose_points(points, scene, s) for s in scenes))


def bake_keyframe_dataset(kfs: KeyframeSet, texels: TexelSpace,
                          lights_train: Sequence[Light], lights_holdout: Sequence[Light],
                          spec: TransportSpec | None = None,
                          timer: StageTimer | None = None):
    """:func:`prtcore.transport.dataset.bake_dataset` per keyframe on the posed scene, texels
    and points, for that keyframe's share of the configurations; the columns are reassembled
    in the order of ``(*lights_train, *lights_holdout)``. ``stats["keyframes"]`` holds each
    keyframe's own transport stats; iterations and residual are the maxima over keyframes.
    Returns a :class:`~prtcore.transport.dataset.Dataset`.
    """
    from prtcore.transport.dataset import Dataset, bake_dataset

    lights = (*tuple(lights_train), *tuple(lights_holdout))
    K = len(lights_train)
    group = np.concatenate([kfs.train, kfs.holdout])
    P, T, N = kfs.points[0].count, texels.count, len(lights)
    direct_p = np.zeros((P, N, 3), np.float32)
    direct_t = np.zeros((T, N, 3), np.float32)
    indirect = np.zeros((T, N, 3), np.float32)
    per_key, iterations, residual = [], 0, 0.0
    for f in range(kfs.count):
        cols = np.flatnonzero(group == f)  # training columns (< K) first, as bake_dataset
        if not len(cols):
            per_key.append(None)
            continue
        d = bake_dataset(kfs.scenes[f], pose_texels(texels, kfs.scenes[f]), kfs.points[f],
                         [lights[i] for i in cols if i < K],
                         [lights[i] for i in cols if i >= K], spec, timer)
        direct_p[:, cols] = d.direct_points
        direct_t[:, cols] = d.direct_texels
        indirect[:, cols] = d.indirect
        iterations = max(iterations, int(d.iterations))
        residual = max(residual, float(d.residual))
        per_key.append(d.stats)
    stats = {"train": K, "holdout": len(lights_holdout), "texels": T, "points": P,
             "keyframes": per_key}
    return Dataset(lights=lights, direct_points=direct_p, direct_texels=direct_t,
                   indirect=indirect, iterations=iterations, residual=residual, stats=stats)


def keyframe_files(directory: Path, kfs: KeyframeSet, rest: Scene) -> dict:
    """Write the per-keyframe posed arrays of a bundle and return the manifest's
    ``keyframes`` section (everything an engine needs to pick and pose a keyframe)."""
    from prtcore.io.bundle import raw_file

    order = export_vertex_order(rest)
    verts = np.stack([np.concatenate([s.positions[order], s.normals[order]], 1)
                      for s in kfs.scenes])
    clusters = np.stack([np.concatenate([p.cluster_position, p.cluster_normal], 1)
                         for p in kfs.points])
    pts = np.stack([np.concatenate([p.position, p.normal], 1) for p in kfs.points])
    return {
        "animation": kfs.animation, "name": kfs.name, "duration": kfs.duration,
        "count": kfs.count, "times": [float(t) for t in kfs.times],
        "transfer": kfs.transfer,
        "selection": "nearest keyframe to the requested time; transfer.matrix has a leading "
                     "keyframe axis when transfer is per_keyframe, else one matrix for all",
        "columns": ["px", "py", "pz", "nx", "ny", "nz"],
        "vertices": raw_file(directory / "keyframe_vertices.bin", verts, "<f4"),
        "vertex_order": "asset.glb vertices in file order (primitives in order, then "
                        "accessor order); faces, UVs and materials are the rest pose's",
        "clusters": raw_file(directory / "keyframe_clusters.bin", clusters, "<f4"),
        "points": raw_file(directory / "keyframe_points.bin", pts, "<f4"),
        "train_keyframe": [int(k) for k in kfs.train],
        "holdout_keyframe": [int(k) for k in kfs.holdout],
    }


# ---------------------------------------------------------------------------------------
# Bundle side


def export_vertex_order(scene: Scene) -> np.ndarray:
    """(V',) int64 scene vertex of each vertex of the exported asset.glb, in file order.

    Mirrors :func:`prtcore.io.gltf.export.scene_to_glb`: one primitive per used material in
    material order, each with the sorted unique vertices its faces use.
    """
    order = []
    for m in range(len(scene.materials)):
        fsel = np.nonzero(scene.face_material == m)[0]
        if len(fsel):
            order.append(np.unique(scene.faces[fsel].ravel()))
    return np.concatenate(order).astype(np.int64) if order else np.zeros(0, np.int64)


def nearest_keyframe(times: Sequence[float], t: float) -> int:
    """Index of the keyframe time closest to t (the earlier one on a tie)."""
    times = np.asarray(times, dtype=np.float64)
    if not len(times):
        raise PrtError("the bundle has no keyframes")
    return int(np.argmin(np.abs(times - float(t))))


def time_outside_warning(keyframes: dict, time: float | None) -> str | None:
    """The one-line warning for a requested ``--time`` outside the animation, else None.

    keyframes : a bundle manifest's ``keyframes`` section. The policy (README): a time
    before 0 or after the animation's duration is not refused; the nearest keyframe is
    used (the first or the last) and this warning says so. Raises :class:`PrtError` for a
    time that is not a finite number (no keyframe is nearest to NaN).
    """
    if time is None or not keyframes:
        return None
    t = float(time)
    if not np.isfinite(t):
        raise PrtError(f"--time {time}: must be a finite number of seconds")
    duration = float(keyframes.get("duration", max(keyframes["times"], default=0.0)))
    if 0.0 <= t <= duration:
        return None
    k = nearest_keyframe(keyframes["times"], t)
    name = keyframes.get("name")
    anim = f"animation {name!r}" if name else "the animation"
    return (f"--time {t:g} s is outside {anim} (0..{duration:g} s); using the nearest "
            f"keyframe, {k} at {keyframes['times'][k]:g} s")


def bundle_at_time(path: str | Path, manifest: dict, data, scene: Scene | None,
                   time: float | None):
    """The runtime data (and the bundle's asset scene) posed at keyframe nearest ``time``.

    data : :class:`~prtcore.runtime.cpu.RuntimeData` of the bundle; scene : its asset.glb as
    loaded (or None). For a static bundle, ``time`` must be None and everything is returned
    unchanged. For a keyframe bundle, ``time=None`` means the first keyframe; a time
    outside the animation takes the nearest keyframe (:func:`time_outside_warning` is the
    message callers print), a non-finite one is refused. The returned
    data has the keyframe's cluster positions/normals and a single (3, n_b, P) transfer
    (that keyframe's, or the shared one). Returns (data, scene, keyframe index or None).
    """
    from prtcore.io.bundle import load_keyframe

    kf = manifest.get("keyframes")
    if not kf:
        if time is not None:
            raise PrtError(f"{path}: --time {time:g}: the bundle was baked without keyframes")
        return data, scene, None
    if time is not None and not np.isfinite(float(time)):
        raise PrtError(f"--time {time}: must be a finite number of seconds")
    k = 0 if time is None else nearest_keyframe(kf["times"], time)
    arrays = load_keyframe(Path(path), manifest, k)
    M, b = data.transfer, data.offset
    if M.ndim == 4:
        M, b = M[k], b[k]
    data = dataclasses.replace(data, transfer=M, offset=b,
                               cluster_position=arrays["clusters"][:, 0:3],
                               cluster_normal=arrays["clusters"][:, 3:6])
    if scene is not None:
        v = arrays["vertices"].astype(np.float64)
        if len(v) != len(scene.positions):
            raise PrtError(f"{path}: keyframe vertices hold {len(v)} rows, asset.glb has "
                           f"{len(scene.positions)} vertices")
        scene = dataclasses.replace(scene, positions=v[:, 0:3], normals=v[:, 3:6])
    return data, scene, k
