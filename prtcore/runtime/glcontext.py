"""OpenGL plumbing of the GL runtime (moderngl, EGL): the context, uniforms, matrices and
the timing of passes. Nothing here knows about bundles (:mod:`prtcore.runtime.gl`)."""

from __future__ import annotations

import functools
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from prtcore.core.errors import PrtError


def create_context(require: int = 430):
    """A standalone headless OpenGL context through EGL (Mesa llvmpipe or a GPU driver)."""
    import moderngl

    try:
        return moderngl.create_context(standalone=True, backend="egl", require=require)
    except Exception as e:  # moderngl raises plain Exceptions for a missing EGL/driver
        raise PrtError(f"render: cannot create an OpenGL {require // 100}.{require % 100 // 10} "
                       f"context through EGL: {e}".replace("\n", " ")) from None


def renderer_label(ctx) -> str:
    """The GL renderer string, marked "(software)" for Mesa's CPU rasterisers."""
    name = str(ctx.info["GL_RENDERER"])
    soft = any(k in name.lower() for k in ("llvmpipe", "softpipe", "swrast", "lavapipe"))
    return f"{name} (software)" if soft else name


def check_gl(ctx, where: str) -> None:
    """Raise if the context has a GL error pending (moderngl reads glGetError)."""
    err = ctx.error
    if err != "GL_NO_ERROR":
        raise PrtError(f"render: {where}: OpenGL error {err}")


def matrix_bytes(m: np.ndarray) -> bytes:
    """Column-major float32 bytes of a square matrix (GLSL's layout)."""
    return np.ascontiguousarray(np.asarray(m, np.float64).T, dtype="<f4").tobytes()


def scene_clip_from_world(camera, center: np.ndarray, radius: float) -> np.ndarray:
    """(4, 4) float64 clip-from-world matrix of a :class:`~prtcore.reference.camera.Camera`
    whose near and far planes bracket a scene's bounding sphere (centre (3,), radius): the
    depth range every camera pass uses."""
    dist = float(np.linalg.norm(camera.position - center))
    near = max(1e-4 * radius, 0.5 * (dist - 1.01 * radius)) \
        if dist > 1.01 * radius else 1e-4 * radius
    return camera.clip_from_view(near, dist + 1.01 * radius) @ camera.view_from_world()


def set_uniform(prog, name: str, value) -> None:
    """Set a uniform if the compiler kept it (unused uniforms are optimised away)."""
    try:
        u = prog[name]
    except KeyError:
        return
    if isinstance(value, bytes):
        u.write(value)
    else:
        u.value = value


def make_current(ctx) -> None:
    """Make ``ctx`` the thread's current context and leave it current.

    Several contexts may live in one process (a test session's and one the CLI creates);
    creating one makes it current, and glcontext's ``with ctx:`` leaves *no* context
    current on exit, so GL methods call this on entry instead of using ``with``.
    """
    ctx.__enter__()


def current(method):
    """Run a GL method with its object's ``ctx`` current (see :func:`make_current`)."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        make_current(self.ctx)
        return method(self, *args, **kwargs)

    return wrapper


def unbind_framebuffer(ctx) -> None:
    """Bind framebuffer 0 before framebuffers are released: moderngl re-binds its
    current framebuffer after creating one, and a deleted one then fails with
    GL_INVALID_OPERATION (a shared context outlives the objects made in it)."""
    ctx.detect_framebuffer(0).use()


class PassTimer:
    """Times each pass twice: a GL timer query (GPU clock) and the wall clock between a
    glFinish before and one after (what a CPU rasteriser actually spends; Mesa's llvmpipe
    runs compute dispatches outside its timer queries, which then read ~0)."""

    def __init__(self, ctx):
        self.ctx = ctx
        self._queries: dict = {}
        self._ran: set[str] = set()
        self._wall: dict[str, float] = {}

    @contextmanager
    def timed(self, name: str) -> Iterator[None]:
        if name not in self._queries:  # moderngl queries are reused, never released
            self._queries[name] = self.ctx.query(time=True)
        q = self._queries[name]
        self.ctx.finish()
        t0 = time.perf_counter()
        with q:
            yield
        self.ctx.finish()
        self._wall[name] = (time.perf_counter() - t0) * 1e3
        self._ran.add(name)

    def reset(self) -> None:
        """Forget which passes ran (a new frame)."""
        self._ran.clear()

    def results(self) -> tuple[dict[str, float | None], dict[str, float]]:
        """Milliseconds of the passes run since :meth:`reset`: by timer query (None where the
        query gave no valid result) and by wall clock."""
        gpu: dict[str, float | None] = {}
        for k in self._ran:
            ns = self._queries[k].elapsed
            # a 32-bit result of all ones: no valid measurement (seen on a first frame)
            gpu[k] = None if ns < 0 or ns >= 0xFFFFFFFF else ns / 1e6
        return gpu, {k: self._wall[k] for k in self._ran}

    def release(self) -> None:
        self._queries.clear()
