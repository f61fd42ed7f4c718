"""Drawing a hair + mesh bundle with the GL renderer (``prtcore render`` on a bundle whose
hair was baked with a mesh, docs/hair.md).

Two renderers in one OpenGL context, one frame: the mesh's
(:class:`prtcore.runtime.gl.BundleRenderer`: its measurement points and coefficients on the
GPU, the lightmap blended per fragment at TEXCOORD_1) and the strands'
(:class:`prtcore.runtime.strands_gl.StrandRenderer`: the fibre tubes, the strand texture
blended at the manifest's sampling rule). They share

* **one shadow atlas** made from both geometries (the tubes and the mesh in one
  position-only buffer): the hair shadows the head and the head the hair;
* **one scene bound** (both's clip planes), so their depths compare;
* **one framebuffer**: the mesh is drawn first, the tubes over it, depth-tested;
* **one set of plane weights**: the strand texture's planes are the atlas's
  (``strands.planes`` in the manifest); the GPU coefficients of the mesh renderer drive
  both.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.scene import Light
from prtcore.reference.camera import Camera
from prtcore.runtime.gl import MODES, BundleRenderer, RenderResult
from prtcore.runtime.glcontext import check_gl, make_current, unbind_framebuffer
from prtcore.runtime.shadows import SHADOW_RESOLUTION, ShadowMaps
from prtcore.runtime.strands_gl import StrandRenderer, tube_vertices


class HairMeshRenderer:
    """The GL drawing of a hair + mesh bundle (see the module docstring). Call
    :meth:`release` (or use as a context manager)."""

    def __init__(self, bundle: str | Path, ctx=None,
                 shadow_resolution: int = SHADOW_RESOLUTION):
        from prtcore.io.bundle import is_hair_mesh, read_manifest

        if not is_hair_mesh(read_manifest(Path(bundle))):
            raise PrtError(f"{bundle}: not a hair + mesh bundle")
        self.mesh = BundleRenderer(bundle, ctx=ctx, shadow_resolution=shadow_resolution)
        try:
            self.strands = StrandRenderer(bundle, ctx=self.mesh.ctx,
                                          shadow_resolution=shadow_resolution)
            self._share(int(shadow_resolution))
        except BaseException:
            self.mesh.release()
            raise

    @property
    def ctx(self):
        return self.mesh.ctx

    def _share(self, resolution: int) -> None:
        """The two renderers' shadow atlas and scene bound made one."""
        sc = self.mesh.scene
        verts, faces = tube_vertices(self.strands.hair)
        positions = np.concatenate([sc.positions, verts[:, :3]]).astype("<f4")
        lo, hi = positions.min(axis=0).astype(np.float64), positions.max(axis=0)
        center = (lo + hi) / 2
        radius = float(max(np.linalg.norm(hi - lo) / 2, 1e-30))
        make_current(self.ctx)
        vbo = self.mesh._keep(self.ctx.buffer(np.ascontiguousarray(positions).tobytes()))
        shadows = ShadowMaps(self.ctx, vbo, "3f", np.concatenate(
            [sc.faces, faces.astype(np.int64) + len(sc.positions)]), center, radius,
            resolution)
        for r in (self.mesh, self.strands):
            unbind_framebuffer(self.ctx)
            r._shadows.release()
            r._shadows = shadows  # the mesh renderer releases it
            r.center, r.radius = center, radius

    def render(self, lights: Sequence[Light], camera: Camera, n: int | None = None,
               mode: str = "full") -> RenderResult:
        """One frame: ``image`` (h, w, 4) float32 linear RGB, A = 1 where the mesh or a
        fibre is seen; mode "full" | "direct" | "indirect"."""
        if mode not in MODES:
            raise PrtError(f"render: mode {mode!r}: expected one of {', '.join(MODES)}")
        m = self.mesh
        m._use(n)
        make_current(self.ctx)
        m._timer.reset()
        m.shadow_pass(lights)
        m.points_pass()
        layers = m.coefficients_pass(n)
        q = len(m.data.plane_element)
        weights = np.frombuffer(m._weights.read(), "<f4").reshape(-1, 4)[:q, :3]
        m.camera_pass(camera, mode, layers)
        fbo = m._target(camera.width, camera.height, 2)
        self.strands.camera_pass(fbo, camera, mode, weights.astype(np.float64), clear=False)
        h, w = camera.height, camera.width
        img = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=0), "<f4")
        check_gl(self.ctx, "render hair + mesh")
        gpu, wall = m._timer.results()
        return RenderResult(image=img.reshape(h, w, 4)[::-1].copy(),
                            uv1=np.zeros((h, w, 2), np.float32), milliseconds=gpu,
                            wall_milliseconds=wall)

    def release(self) -> None:
        self.strands._shadows = None  # shared: released once, with the mesh renderer
        self.strands.release()
        self.mesh.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.release()
