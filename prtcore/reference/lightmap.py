"""Lightmaps in the texel space of an asset or a bundle: rebuilding that texel space, and
the path-traced reference written as an atlas EXR (``prtcore reference``)."""

from __future__ import annotations

from pathlib import Path

from prtcore.core.progress import StageTimer
from prtcore.core.scene import Scene
from prtcore.receivers.texels import TexelSpace


def texel_space_for(source: str | Path, spec_path: str | Path | None = None, *,
                    quiet: bool = True, timer: StageTimer | None = None
                    ) -> tuple[Scene, TexelSpace]:
    """The scene and texel space of an asset (prepared with the spec) or of a bundle
    (its asset.glb at the bundle's atlas size), so that outputs line up texel for texel."""
    from prtcore.core.spec import load_spec
    from prtcore.intake.prepare import prepare_scene
    from prtcore.io.gltf.loader import load_asset
    from prtcore.receivers.texels import build_texel_space

    timer = timer or StageTimer(quiet=quiet)
    source = Path(source)
    if source.is_dir():
        from prtcore.io.bundle import read_manifest

        m = read_manifest(source)
        with timer.stage("load"):
            scene = load_asset(source / m["asset"]["file"])
        w, h, pad = m["atlas"]["width"], m["atlas"]["height"], m["atlas"]["padding"]
    else:
        spec = load_spec(spec_path)
        with timer.stage("load"):
            scene = load_asset(source)
        scene, _ = prepare_scene(scene, spec, timer=timer)
        w = h = spec.atlas.resolution
        pad = spec.atlas.padding
    with timer.stage("texels"):
        texels = build_texel_space(scene, w, h, padding=pad)
    return scene, texels


def reference_to_exr(source: str | Path, light_path: str | Path, out: Path, *, spp: int,
                     seed: int = 0, spec_path: str | Path | None = None,
                     quiet: bool = False) -> Path:
    """``prtcore reference``: the path-traced indirect lightmap as an RGBA EXR."""
    from prtcore.core.errors import PrtError
    from prtcore.emitters.lightfile import load_light_file
    from prtcore.io.imageio import write_exr
    from prtcore.receivers.texels import texels_to_image
    from prtcore.reference.pathtracer import reference_lightmap

    if spp < 1:
        raise PrtError(f"--spp must be ≥ 1, got {spp}")
    lights = load_light_file(light_path)  # validate before the expensive part
    timer = StageTimer(quiet=quiet)
    scene, texels = texel_space_for(source, spec_path, timer=timer)
    values = reference_lightmap(scene, texels, lights, spp, seed=seed, timer=timer)
    write_exr(out, texels_to_image(texels, values, dilate=False), dtype="float")
    return Path(out)
