"""Plain data for a loaded, flattened scene (world space, metres, +Y up).

Produced by :mod:`prtcore.io.gltf.loader`, consumed by every later stage. All arrays are numpy;
all dataclasses are frozen. Vertices are *not* welded across primitives: each glTF
primitive instance (a mesh primitive under a node) contributes its own vertex range.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Texture:
    """A decoded texture (base colour, or a normal map).

    pixels : (h, w, 4) float32, *linear* RGBA (sRGB already decoded for colour; a normal
        map's values as stored, in [0, 1]), row 0 = image top.
    wrap_s, wrap_t : glTF sampler wrap modes (10497 REPEAT, 33071 CLAMP, 33648 MIRRORED).
    """

    pixels: np.ndarray
    wrap_s: int = 10497
    wrap_t: int = 10497
    name: str = ""


@dataclass(frozen=True)
class Subsurface:
    """A homogeneous scattering medium filling the closed mesh of a translucent material
    (docs/subsurface.md), behind a Lambertian-transmitting boundary.

    sigma_t : (3,) float64 extinction coefficient σ_t = σ_s + σ_a per channel (per world
        unit, the inverse mean free path)
    albedo : (3,) float64 single-scattering albedo α = σ_s / σ_t per channel, in [0, 1]
    anisotropy : Henyey–Greenstein g of the phase function, in (−1, 1)
    transmission : t, the boundary's diffuse transmission factor in [0, 1]
        (KHR_materials_diffuse_transmission): it reflects ``(1 − t) · base colour`` and
        transmits ``t · transmission_color``; the transport's boundary is symmetric, with
        the mean of the two as its albedo on both sides
        (:func:`prtcore.core.materials.albedo_at`, docs/subsurface.md)
    transmission_color : (3,) float64 linear (diffuseTransmissionColorFactor)
    """

    sigma_t: np.ndarray
    albedo: np.ndarray
    anisotropy: float = 0.0
    transmission: float = 0.5
    transmission_color: np.ndarray = field(default_factory=lambda: np.ones(3))


@dataclass(frozen=True)
class Material:
    """Lambertian transport material taken from glTF pbrMetallicRoughness.

    base_color_factor : (4,) float64 linear RGBA
    texture : index into ``Scene.textures`` or -1
    uv_transform : (3, 3) float64, KHR_texture_transform as a matrix acting on
        homogeneous TEXCOORD_0 (identity when absent)
    texcoord : which TEXCOORD_n the base-colour texture reads (0 unless the asset says)
    emissive_factor : (3,) float64 (recorded; transport ignores emission, see README)
    subsurface : the medium inside, when the material is translucent (None: opaque)
    normal_texture : index into ``Scene.textures`` of the tangent-space normal map
        (glTF ``normalTexture``, pixels kept *linear*: no sRGB decoding) or -1
    normal_scale : the normalTexture's ``scale`` (multiplies the map's X and Y)
    normal_texcoord, normal_uv_transform : which TEXCOORD_n the normal map reads and its
        KHR_texture_transform (as ``texcoord`` / ``uv_transform``); the tangent frame comes
        from that UV set (:func:`prtcore.core.geometry.uv_tangent_frames`)
    """

    name: str
    base_color_factor: np.ndarray
    texture: int = -1
    uv_transform: np.ndarray = field(default_factory=lambda: np.eye(3))
    texcoord: int = 0
    emissive_factor: np.ndarray = field(default_factory=lambda: np.zeros(3))
    double_sided: bool = False
    subsurface: Subsurface | None = None
    normal_texture: int = -1
    normal_scale: float = 1.0
    normal_texcoord: int = 0
    normal_uv_transform: np.ndarray = field(default_factory=lambda: np.eye(3))


@dataclass(frozen=True)
class Light:
    """A KHR_lights_punctual light in world space (docs/lights.md).

    color : (3,) float64 linear RGB; intensity in cd (point/spot) or lux (directional)
    position : (3,) float64; direction : (3,) float64 unit, the direction light travels
    inner_cone_angle, outer_cone_angle : radians (spot only)
    range : float or None (None = infinite)
    environment : type ``environment`` only: ``"sky"`` (the analytic sky about the sun
        direction −direction) or an equirect map file turned about +y by the azimuth of
        −direction (:mod:`prtcore.emitters.environment_light`); empty for other types
    """

    type: str
    color: np.ndarray
    intensity: float
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))
    inner_cone_angle: float = 0.0
    outer_cone_angle: float = np.pi / 4
    range: float | None = None
    name: str = ""
    environment: str = ""


@dataclass(frozen=True)
class Node:
    """A glTF node at rest: local TRS (or matrix), parent, mesh/skin references.

    translation (3,), rotation (4,) quaternion xyzw, scale (3,) float64;
    matrix (4, 4) float64 local transform (column vectors, i.e. ``world = parent @ local``);
    world_from_node : (4, 4) float64 at rest.
    """

    name: str
    parent: int
    children: tuple[int, ...]
    translation: np.ndarray
    rotation: np.ndarray
    scale: np.ndarray
    matrix: np.ndarray
    world_from_node: np.ndarray
    mesh: int = -1
    skin: int = -1


@dataclass(frozen=True)
class AnimationChannel:
    """One sampler+target: node ``node``'s ``path`` (translation|rotation|scale|weights).

    times : (k,) float64 seconds; values : (k, c) float64 (c = 3 or 4; CUBICSPLINE keeps
    in-tangent, value, out-tangent rows as (3k, c)); interpolation : LINEAR|STEP|CUBICSPLINE
    """

    node: int
    path: str
    times: np.ndarray
    values: np.ndarray
    interpolation: str = "LINEAR"


@dataclass(frozen=True)
class Animation:
    name: str
    channels: tuple[AnimationChannel, ...]

    @property
    def duration(self) -> float:
        return max((float(c.times[-1]) for c in self.channels if len(c.times)), default=0.0)


@dataclass(frozen=True)
class Skin:
    """joints : (j,) int node indices; inverse_bind : (j, 4, 4) float64; skeleton : int."""

    name: str
    joints: np.ndarray
    inverse_bind: np.ndarray
    skeleton: int = -1


@dataclass(frozen=True)
class PrimitiveInstance:
    """One mesh primitive placed by one node: how to re-pose it later (keyframes).

    vertex_start/vertex_count and face_start/face_count index into the Scene arrays.
    object_positions (v, 3), object_normals (v, 3) float64 in the node's (mesh) space;
    joints (v, 4) int32 and weights (v, 4) float64 when skinned, else empty (0, 4).
    """

    node: int
    mesh: int
    primitive: int
    vertex_start: int
    vertex_count: int
    face_start: int
    face_count: int
    object_positions: np.ndarray
    object_normals: np.ndarray
    joints: np.ndarray
    weights: np.ndarray


@dataclass(frozen=True)
class Scene:
    """The flattened scene.

    positions : (v, 3) float64 world
    normals : (v, 3) float64 world, unit (computed area-weighted when the asset has none)
    uv0 : (v, 2) float64 TEXCOORD_0 (zeros where absent; see ``has_uv0``)
    uv1 : (v, 2) float64 TEXCOORD_1 or None when no primitive has it
    faces : (f, 3) int64 vertex indices, counter-clockwise front faces
    face_material : (f,) int32 index into ``materials`` (a default grey material is appended
        for primitives without one)
    face_instance : (f,) int32 index into ``instances``
    """

    source: str
    positions: np.ndarray
    normals: np.ndarray
    uv0: np.ndarray
    uv1: np.ndarray | None
    faces: np.ndarray
    face_material: np.ndarray
    face_instance: np.ndarray
    materials: tuple[Material, ...]
    textures: tuple[Texture, ...] = ()
    lights: tuple[Light, ...] = ()
    nodes: tuple[Node, ...] = ()
    instances: tuple[PrimitiveInstance, ...] = ()
    animations: tuple[Animation, ...] = ()
    skins: tuple[Skin, ...] = ()
    has_uv0: np.ndarray | None = None  # (v,) bool
    warnings: tuple[str, ...] = ()

    @property
    def triangle_count(self) -> int:
        return len(self.faces)

    @cached_property
    def _used_positions(self) -> np.ndarray:
        """(u, 3) positions of the vertices that some face references."""
        if not len(self.faces):
            return self.positions
        used = np.zeros(len(self.positions), dtype=bool)
        used[self.faces.ravel()] = True
        return self.positions[used]

    @cached_property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64 axis-aligned bounds of the referenced vertices."""
        p = self._used_positions
        return np.stack([p.min(axis=0), p.max(axis=0)])

    @property
    def center(self) -> np.ndarray:
        """(3,) float64 centre of the bounding box."""
        return self.bounds.mean(axis=0)

    @cached_property
    def radius(self) -> float:
        """Bounding-sphere radius around :attr:`center` (the scene scale for tolerances)."""
        p = self._used_positions
        return float(np.sqrt(((p - self.center) ** 2).sum(axis=1).max()))

    def face_areas(self) -> np.ndarray:
        """(f,) float64 triangle areas."""
        v = self.positions[self.faces]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)

    def face_normals(self) -> np.ndarray:
        """(f,) geometric unit normals (zero for degenerate faces)."""
        v = self.positions[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        ln = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, ln, out=np.zeros_like(n), where=ln > 0)

    def replace(self, **changes) -> Scene:
        import dataclasses
        return dataclasses.replace(self, **changes)


def single_mesh_scene(source: str, positions: np.ndarray, normals: np.ndarray,
                      faces: np.ndarray, material: Material, *,
                      uv0: np.ndarray | None = None, has_uv0: np.ndarray | None = None,
                      warnings: tuple[str, ...] = ()) -> Scene:
    """A scene of one untransformed mesh with one material (OBJ/PLY assets, SDF meshes):
    positions, normals (v, 3) float64, faces (f, 3) int64; uv0 (v, 2) with has_uv0 (v,)
    bool, or none."""
    nv = len(positions)
    if uv0 is None:
        uv0, has_uv0 = np.zeros((nv, 2)), np.zeros(nv, dtype=bool)
    empty4 = np.zeros((0, 4))
    inst = PrimitiveInstance(node=-1, mesh=0, primitive=0, vertex_start=0, vertex_count=nv,
                             face_start=0, face_count=len(faces), object_positions=positions,
                             object_normals=normals, joints=empty4.astype(np.int32),
                             weights=empty4)
    return Scene(source=source, positions=positions, normals=normals, uv0=uv0, uv1=None,
                 faces=faces, face_material=np.zeros(len(faces), dtype=np.int32),
                 face_instance=np.zeros(len(faces), dtype=np.int32), materials=(material,),
                 instances=(inst,), has_uv0=has_uv0, warnings=warnings)
