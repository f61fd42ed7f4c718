"""Headless OpenGL runtime of ``sh_prt`` bundles (docs/sh_prt.md): one camera pass.

* vertex storage — the vertex-shader variant (Sloan et al. 2002): each vertex reads its
  transfer vector (L² per channel) from a storage buffer and dots it with the light's SH;
  the rasteriser interpolates the colour;
* texture storage — the fragment-shader variant (transfer textures): the transfer
  textures, one RGBA layer per four coefficients of a channel in a texture array, are
  filtered bilinearly at TEXCOORD_1 and dotted with the light's SH per fragment.

The light's SH (distant lighting: an environment, rotated on the CPU by
:func:`prtcore.core.sh.rotate`, plus directional lights) is a storage buffer uploaded per
frame. Images as :mod:`prtcore.runtime.gl`: float RGBA, row 0 at the top, A = 1 where the
pixel sees the front of a surface. The pass is timed with a GL timer query and the wall
clock (:class:`prtcore.runtime.glcontext.PassTimer`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.reference.camera import Camera
from prtcore.runtime.gl import GLRenderer, RenderResult, draw_depth_tested
from prtcore.runtime.glcontext import (
    check_gl,
    current,
    matrix_bytes,
    scene_clip_from_world,
    set_uniform,
)
from prtcore.runtime.glsl import shader_source

#: position, normal and TEXCOORD_1 of the scene buffer
SH_VERTEX_FORMAT = "3f 3f 2f"
#: most bands of the glossy layer in GLSL (sh_basis.glsl's SH_MAX_BANDS)
GLOSSY_MAX_BANDS = 8


def glossy_constants(bands: int, exponent: float) -> tuple[bytes, bytes]:
    """The glossy layer's constant buffers (``sh_glossy.glsl``): the Phong lobe's
    Funk–Hecke kernel (L²,) and the basis normalisation K_l^m (GLOSSY_MAX_BANDS²), float32
    bytes. Refuses more than :data:`GLOSSY_MAX_BANDS` bands."""
    from prtcore.core import sh

    if bands > GLOSSY_MAX_BANDS:
        raise PrtError(f"the GL glossy layer takes at most {GLOSSY_MAX_BANDS} bands, got "
                       f"{bands}")
    kernel = sh.zonal_kernel(sh.phong_zonal(exponent, bands))
    norm = np.zeros((GLOSSY_MAX_BANDS, GLOSSY_MAX_BANDS), np.float32)
    norm[:bands, :bands] = sh.normalisation(bands)
    return np.asarray(kernel, "<f4").tobytes(), norm.tobytes()


def product_matrices(light: np.ndarray) -> bytes:
    """The triple product's matrices of light SH (L², 3), written once per frame:
    M_c[k, j] = Σ_i Γ_ijk l_ic, (3, L², L²) float32 bytes."""
    from prtcore.core import sh

    mats = np.stack([sh.product_matrix(light[:, ch]) for ch in range(3)])
    return np.ascontiguousarray(mats, "<f4").tobytes()


class DistantPass(GLRenderer):
    """A camera pass over a bundle's asset under distant lighting (the sh_prt and
    learnt_sh runtimes): the manifest checked for ``method``, the asset's positions,
    normals and TEXCOORD_1 in a vertex array drawn with ``sh_vs.glsl`` and ``fragment``
    (a shader source) — or with ``fullscreen`` one triangle over the viewport
    (``atlas_vs.glsl``, for a fragment shader that finds its own surface); ``setup`` makes
    the subclass's GL objects. Lifecycle and framebuffers: :class:`GLRenderer`."""

    def __init__(self, bundle: str | Path, method: str, fragment: str, ctx=None, *,
                 fullscreen: bool = False, setup=None):
        import moderngl

        from prtcore.io.bundle import read_manifest
        from prtcore.io.gltf.loader import load_asset

        self.bundle = Path(bundle)
        self.manifest = read_manifest(self.bundle)
        if self.manifest.get("method") != method:
            raise PrtError(f"{self.bundle}: not an {method} bundle")
        self.scene = load_asset(self.bundle / self.manifest["asset"]["file"])
        if self.scene.uv1 is None:
            raise PrtError(f"{self.bundle}: asset.glb has no TEXCOORD_1")
        self.center = np.asarray(self.scene.center, np.float64)
        self.radius = float(max(self.scene.radius, 1e-30))
        self._mgl = moderngl
        self._fullscreen = fullscreen

        def open_pass() -> None:
            sc, c = self.scene, self.ctx
            self._prog = self._keep(c.program(
                vertex_shader=shader_source("atlas_vs.glsl" if fullscreen else "sh_vs.glsl"),
                fragment_shader=fragment))
            if fullscreen:
                self._vao = self._keep(c.vertex_array(self._prog, []))
            else:
                verts = np.concatenate([sc.positions, sc.normals, sc.uv1], axis=1)
                vbo = self._keep(c.buffer(np.ascontiguousarray(verts, "<f4").tobytes()))
                ibo = self._keep(c.buffer(np.ascontiguousarray(sc.faces, "<u4").tobytes()))
                self._vao = self._keep(c.vertex_array(
                    self._prog, [(vbo, SH_VERTEX_FORMAT, "in_pos", "in_nrm", "in_uv1")],
                    index_buffer=ibo, index_element_size=4))
            if setup is not None:
                setup()

        self._open(ctx, open_pass)

    def _upload_light(self, light_sh: np.ndarray, rows: int, glossy: bool) -> None:
        """Write light SH (L², 3) into ``self._light`` (``rows`` vec4s, binding 6) and,
        for a glossy layer, its triple-product matrices into ``self._product``."""
        n = self.bands ** 2
        light = np.asarray(light_sh, np.float64)
        if light.shape != (n, 3):
            raise PrtError(f"render: light SH of shape {light.shape}; expected ({n}, 3)")
        buf = np.zeros((rows, 4), "<f4")
        buf[:n, :3] = light
        self._light.write(buf.tobytes())
        if glossy:
            self._product.write(product_matrices(light))

    def _draw(self, camera: Camera, name: str) -> RenderResult:
        """Draw the asset through ``camera`` (uniforms and buffers already set) as the
        timed pass ``name``; the frame, row 0 at the top."""
        fbo = self._target(camera.width, camera.height, 1)
        if not self._fullscreen:
            clip = scene_clip_from_world(camera, self.center, self.radius)
            set_uniform(self._prog, "clip_from_world", matrix_bytes(clip))
        set_uniform(self._prog, "eye", tuple(float(v) for v in camera.position))
        self._timer.reset()
        with self._timer.timed(name):
            draw_depth_tested(self.ctx, fbo, lambda: self._vao.render(
                self._mgl.TRIANGLES, vertices=3 if self._fullscreen else -1))
        h, w = camera.height, camera.width
        img = np.frombuffer(fbo.read(components=4, dtype="f4"), "<f4").reshape(h, w, 4)
        check_gl(self.ctx, f"{name} render")
        gpu, wall = self._timer.results()
        return RenderResult(image=img[::-1].copy(), uv1=np.zeros((h, w, 2), np.float32),
                            milliseconds=gpu, wall_milliseconds=wall)


class ShPrtRenderer(DistantPass):
    """The GPU runtime of one sh_prt bundle (the manifest's ``sh_prt`` section)."""

    def __init__(self, bundle: str | Path, ctx=None):
        super().__init__(bundle, "sh_prt", shader_source("sh_fs.glsl"), ctx,
                         setup=self._setup)

    def _setup(self) -> None:
        """The transfer (vertex buffer or texture array), glossy layer and light buffer."""
        from prtcore.io.bundle import load_raw
        from prtcore.io.transfer_textures import read_transfer_textures

        sec = self.manifest["sh_prt"]
        self.bands, self.storage = int(sec["bands"]), sec["storage"]
        self.files = math.ceil(self.bands ** 2 / 4)
        c = self.ctx
        self._setup_glossy(sec.get("glossy"))
        if self.storage == "vertex":
            t = load_raw(self.bundle, sec["vertex_transfer"]).astype("<f4")
            self._transfer = self._keep(c.buffer(np.ascontiguousarray(t).tobytes()))
            self._tex = self._keep(c.texture_array((1, 1, 1), 4, dtype="f4"))
        else:
            img = read_transfer_textures(self.bundle, self.bands)  # (H, W, 3, L²)
            h, w = img.shape[:2]
            pad = np.zeros((h, w, 3, 4 * self.files), np.float32)
            pad[..., :self.bands ** 2] = img
            layers = pad.reshape(h, w, 3, self.files, 4).transpose(2, 3, 0, 1, 4)
            self._tex = self._keep(c.texture_array(
                (w, h, 3 * self.files), 4,
                np.ascontiguousarray(layers.reshape(-1, h, w, 4), "<f4").tobytes(),
                dtype="f4"))
            self._tex.filter = (self._mgl.LINEAR, self._mgl.LINEAR)
            self._tex.repeat_x = self._tex.repeat_y = False
            self._transfer = self._keep(c.buffer(reserve=16))
        self._light = self._keep(c.buffer(reserve=16 * 4 * self.files))

    def _setup_glossy(self, glossy: dict | None) -> None:
        """The glossy layer (TP): visibility textures (one RGBA layer per four
        coefficients), the Phong kernel, the basis normalisation; the product matrices are
        written per frame."""
        from prtcore.io.transfer_textures import VISIBILITY, read_transfer_textures

        c, n = self.ctx, self.bands ** 2
        self.glossy = glossy
        if glossy is None:
            self._vis = self._keep(c.texture_array((1, 1, 1), 4, dtype="f4"))
            for name in ("_product", "_kernel", "_norm"):
                setattr(self, name, self._keep(c.buffer(reserve=16)))
            return
        if self.bands > GLOSSY_MAX_BANDS:
            raise PrtError(f"{self.bundle}: the GL glossy layer takes at most "
                           f"{GLOSSY_MAX_BANDS} bands, the bundle has {self.bands}")
        vis = read_transfer_textures(self.bundle, self.bands, VISIBILITY)[:, :, 0]
        h, w = vis.shape[:2]
        pad = np.zeros((h, w, 4 * self.files), np.float32)
        pad[..., :n] = vis
        layers = pad.reshape(h, w, self.files, 4).transpose(2, 0, 1, 3)
        self._vis = self._keep(c.texture_array((w, h, self.files), 4, np.ascontiguousarray(
            layers, "<f4").tobytes(), dtype="f4"))
        self._vis.filter = (self._mgl.LINEAR, self._mgl.LINEAR)
        self._vis.repeat_x = self._vis.repeat_y = False
        kernel, norm = glossy_constants(self.bands, float(glossy["exponent"]))
        self._kernel = self._keep(c.buffer(kernel))
        self._norm = self._keep(c.buffer(norm))
        self._product = self._keep(c.buffer(reserve=4 * 3 * n * n))

    @current
    def render(self, light_sh: np.ndarray, camera: Camera) -> RenderResult:
        """One frame under light SH coefficients (L², 3) through ``camera``."""
        n = self.bands ** 2
        self._upload_light(light_sh, 4 * self.files, self.glossy is not None)
        prog = self._prog
        set_uniform(prog, "vertex_storage", int(self.storage == "vertex"))
        set_uniform(prog, "n_coeffs", n)
        set_uniform(prog, "files", self.files)
        set_uniform(prog, "transfer_tex", 0)
        set_uniform(prog, "visibility_tex", 1)
        set_uniform(prog, "glossy", int(self.glossy is not None))
        set_uniform(prog, "specular", float((self.glossy or {}).get("specular", 0.0)))
        set_uniform(prog, "bands", self.bands)
        self._tex.use(location=0)
        self._vis.use(location=1)
        self._transfer.bind_to_storage_buffer(5)
        self._light.bind_to_storage_buffer(6)
        self._product.bind_to_storage_buffer(7)
        self._kernel.bind_to_storage_buffer(8)
        self._norm.bind_to_storage_buffer(9)
        return self._draw(camera, f"sh_{self.storage}")


def render_sh_prt_to_file(bundle: str | Path, light_path: str | Path,
                          camera_path: str | Path, out: str | Path, *, exposure: float = 1.0
                          ) -> tuple[RenderResult, str]:
    """``prtcore render`` of an sh_prt bundle: distant lighting (docs/lights.md) → one frame
    to a PNG or EXR. Returns the frame and the GL renderer's label."""
    return render_distant_to_file(ShPrtRenderer, bundle, light_path, camera_path, out,
                                  exposure=exposure)


def render_distant_to_file(renderer: type, bundle: str | Path, light_path: str | Path,
                           camera_path: str | Path, out: str | Path, *,
                           exposure: float = 1.0) -> tuple[RenderResult, str]:
    """One frame of a bundle drawn by ``renderer`` (a :class:`DistantPass` with
    ``bands`` and ``render(light_sh, camera)``) under a distant-light file, to a PNG or
    EXR. Returns the frame and the GL renderer's label."""
    from prtcore.emitters.environment import load_distant_lighting
    from prtcore.reference.camera import load_camera
    from prtcore.runtime.gl import write_render
    from prtcore.runtime.glcontext import renderer_label

    if Path(out).suffix.lower() not in (".png", ".exr"):
        raise PrtError(f"{out}: output must end in .png or .exr")
    lighting = load_distant_lighting(light_path)
    camera = load_camera(camera_path)
    with renderer(bundle) as r:
        res = r.render(lighting.sh_coefficients(r.bands), camera)
        label = renderer_label(r.ctx)
    write_render(out, res.image, exposure)
    return res, label
