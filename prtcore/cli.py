"""The ``prtcore`` command: a thin shell over the library (README, "The command line").

Every :class:`prtcore.core.errors.PrtError` becomes exit status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from prtcore.core.errors import PrtError


def _cmd_plan(args: argparse.Namespace) -> int:
    from prtcore.core.spec import load_spec
    from prtcore.intake.plan import plan_asset
    from prtcore.io.gltf.loader import load_asset

    spec = load_spec(args.spec)
    scene = load_asset(args.asset)
    print(f"asset     {args.asset}: {scene.triangle_count} triangles, "
          f"{len(scene.materials)} materials, {len(scene.lights)} lights, "
          f"{len(scene.animations)} animations")
    print(plan_asset(scene, spec).format())
    return 0


def _cmd_intake(args: argparse.Namespace) -> int:
    """Run the intake stages (load → prepare → texels → points) and print a summary."""
    from prtcore.core.spec import load_spec
    from prtcore.pipeline import run_intake

    spec = load_spec(args.spec)
    result = run_intake(args.asset, spec, quiet=args.quiet)
    print(result.summary())
    return 0


def _cmd_bake(args: argparse.Namespace) -> int:
    from prtcore.core.spec import load_spec
    from prtcore.io.bundle import read_manifest
    from prtcore.pipeline import bake
    from prtcore.verdict import EXIT_POOR

    spec = load_spec(args.spec)
    out = bake(args.asset, spec, Path(args.out), quiet=args.quiet, force=args.force,
               mesh=args.mesh)
    print(f"bundle: {out}")
    print(f"report: {out / 'report.json'}")
    verdict = read_manifest(out).get("verdict") or {}
    if verdict.get("line"):
        print(verdict["line"])  # the bake's last line, also with -q
    if verdict.get("status") == "fail" and not args.allow_poor:
        return EXIT_POOR
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from prtcore.compare import CompareOptions, compare, expected_ordering, format_compare
    from prtcore.core.spec import load_spec

    spec = load_spec(args.spec) if args.spec else None
    if args.asset is None and spec is not None:
        raise PrtError("compare: --spec needs an asset (the built scene has its own spec)")
    opt = CompareOptions(spp=args.spp, bands=args.bands, strata=args.strata,
                         lights=args.lights, seed=args.seed)
    result = compare(args.out, asset=args.asset, spec=spec, options=opt, quiet=args.quiet)
    print(format_compare(result))
    for line in expected_ordering(result):
        print(f"prtcore compare: note: {line}")
    print(f"compare: {Path(args.out) / 'compare.txt'}, {Path(args.out) / 'compare_strip.png'}")
    return 0


def _cmd_reference(args: argparse.Namespace) -> int:
    from prtcore.reference.lightmap import reference_to_exr

    if args.camera:  # camera-space ground truth for `prtcore render`
        from prtcore.reference.camera import reference_view_to_exr

        component = "indirect" if args.indirect_only else "direct" if args.no_indirect \
            else "full"
        reference_view_to_exr(args.source, args.light, args.camera, Path(args.out),
                              spp=args.spp, seed=args.seed, component=component,
                              quiet=args.quiet)
        print(f"reference: {args.out} ({component})")
        return 0
    if args.indirect_only or args.no_indirect:
        raise PrtError("reference: --indirect-only/--no-indirect need --camera")
    reference_to_exr(args.source, args.light, Path(args.out), spp=args.spp, seed=args.seed,
                     spec_path=args.spec, quiet=args.quiet)
    print(f"reference: {args.out}")
    return 0


def _warn_time(command: str, manifest: dict, time: float | None) -> None:
    """``--time`` outside the animation: one warning line on stderr; the nearest keyframe
    is used (README, "The bake spec"). A non-finite time is refused (exit 2)."""
    from prtcore.keyframes.pose import time_outside_warning

    msg = time_outside_warning(manifest.get("keyframes") or {}, time)
    if msg:
        print(f"prtcore {command}: warning: {msg}", file=sys.stderr)


def _posed_runtime(command: str, bundle: Path, time: float | None):
    """(manifest, runtime data, scene, keyframe) of a bundle, posed at the keyframe nearest
    ``time`` for keyframe bundles (with the --time warning)."""
    from prtcore.intake.hair import hair_scene
    from prtcore.io.bundle import load_runtime, read_manifest
    from prtcore.io.gltf.loader import load_asset
    from prtcore.io.hair import is_hair_file, load_hair

    manifest = read_manifest(bundle)
    data = load_runtime(bundle, manifest)
    asset = bundle / manifest["asset"]["file"]
    if is_hair_file(asset):  # a hair bundle: the fibres shadow the measurement points
        scene = hair_scene(load_hair(asset))
    elif manifest["asset"].get("hair"):  # hair + mesh: both shadow them
        from prtcore.intake.hair import with_hair

        scene = with_hair(load_asset(asset),
                          load_hair(bundle / manifest["asset"]["hair"]["file"]))
    else:
        scene = load_asset(asset)
    key = None
    if manifest.get("keyframes") or time is not None:  # pose at the nearest keyframe
        from prtcore.keyframes.pose import bundle_at_time

        _warn_time(command, manifest, time)
        data, scene, key = bundle_at_time(bundle, manifest, data, scene, time)
    return manifest, data, scene, key


def _warn_family(command: str, data, lights, tracer) -> None:
    """One warning line on stderr when the lights lie outside the family the bake was
    trained on (prtcore.runtime.family), with the measure."""
    from prtcore.runtime.cpu import shade_points
    from prtcore.runtime.family import family_residual

    if data.direct_span is None:
        return
    r = family_residual(data.direct_span.T, shade_points(data, lights, tracer))
    if r > data.family_warn_above:
        print(f"prtcore {command}: warning: light outside the trained family: "
              f"{100 * r:.1f} % of its direct vector at the measurement points lies outside "
              f"the span of the training lights (warning above "
              f"{100 * data.family_warn_above:.1f} %); its error is not bounded by the "
              "bake's held-out figures", file=sys.stderr)


#: methods whose bundles take distant lighting (docs/sh_prt.md, docs/learnt_sh.md)
DISTANT_METHODS = ("sh_prt", "learnt_sh")


def _relight_distant(args: argparse.Namespace, bundle: Path, method: str) -> int:
    """relight of an sh_prt or learnt_sh bundle: distant lighting (an environment map
    and/or directional lights, docs/sh_prt.md) → the lightmap of outgoing radiance."""
    from prtcore.emitters.environment import load_distant_lighting
    from prtcore.io.bundle import read_manifest
    from prtcore.io.imageio import write_exr

    if method == "sh_prt":
        from prtcore.methods.sh_prt import relight_bundle
    else:
        from prtcore.methods.learnt_sh import relight_bundle
    for flag, value in (("--time", args.time), ("--basis", args.basis)):
        if value is not None:
            raise PrtError(f"{flag}: an {method} bundle has no keyframes or basis")
    manifest = read_manifest(bundle)
    image = relight_bundle(bundle, manifest, load_distant_lighting(args.light))
    write_exr(args.out, image, dtype="float")
    sec = manifest[method]
    kind = f"sh_prt {sec['storage']}" if method == "sh_prt" else \
        f"learnt_sh k{sec['width']} l{sec['layers']}"
    print(f"relit: {args.out} ({image.shape[1]}×{image.shape[0]}, {kind}, "
          f"{sec['bands']} bands)")
    return 0


def _cmd_relight(args: argparse.Namespace) -> int:
    from prtcore.core.raytrace import RayTracer
    from prtcore.emitters.lightfile import load_light_file
    from prtcore.io.bundle import is_hair_mesh, read_manifest, strand_runtime
    from prtcore.io.imageio import write_exr
    from prtcore.runtime.cpu import relight

    bundle = Path(args.bundle)
    method = read_manifest(bundle).get("method")
    if method in DISTANT_METHODS:
        return _relight_distant(args, bundle, method)
    manifest, data, scene, key = _posed_runtime("relight", bundle, args.time)
    lights = load_light_file(args.light)
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    if args.basis is not None and not 1 <= args.basis <= data.n_basis:
        raise PrtError(f"--basis {args.basis}: the bundle has {data.n_basis} basis elements "
                       f"(mean included); use 1..{data.n_basis}")
    _warn_family("relight", data, lights, tracer)
    image = relight(data, lights, tracer, n=args.basis)
    write_exr(args.out, image, dtype="float")
    print(f"relit: {args.out} ({image.shape[1]}×{image.shape[0]}, "
          f"{args.basis or data.n_basis} basis elements"
          + ("" if key is None else f", keyframe {key} at "
             f"{manifest['keyframes']['times'][key]:g} s") + ")")
    if is_hair_mesh(manifest):  # the strand texture too, from the same plane weights
        out = Path(args.out)
        strands_out = out.with_name(f"{out.stem}.strands{out.suffix or '.exr'}")
        image = relight(strand_runtime(bundle, manifest, data), lights, tracer, n=args.basis)
        write_exr(strands_out, image, dtype="float")
        print(f"relit: {strands_out} ({image.shape[1]}×{image.shape[0]}, the strand "
              f"texture)")
    return 0


def _render_distant(args: argparse.Namespace, method: str) -> int:
    """render of an sh_prt bundle (the vertex- or fragment-shader variant, docs/sh_prt.md)
    or a learnt_sh bundle (the network per fragment, docs/learnt_sh.md) under distant
    lighting."""
    if method == "sh_prt":
        from prtcore.runtime.sh_gl import render_sh_prt_to_file as render_file
    else:
        from prtcore.runtime.learnt_sh import render_learnt_sh_to_file as render_file

    for flag, value in (("--time", args.time), ("--basis", args.basis),
                        ("--indirect-only", args.indirect_only or None),
                        ("--no-indirect", args.no_indirect or None),
                        ("--cpu", args.cpu or None)):
        if value is not None:
            raise PrtError(f"render: {flag}: not an option for an {method} bundle")
    res, label = render_file(args.bundle, args.light, args.camera, args.out,
                             exposure=args.exposure)
    times = ", ".join(f"{k} {v:.2f} ms" for k, v in res.wall_milliseconds.items())
    print(f"rendered: {args.out} ({res.image.shape[1]}×{res.image.shape[0]}, {method}) on "
          f"{label}; first frame, wall clock: {times}")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from prtcore.io.bundle import read_manifest
    from prtcore.runtime.gl import render_to_file

    method = read_manifest(Path(args.bundle)).get("method")
    if method in DISTANT_METHODS:
        return _render_distant(args, method)
    if args.indirect_only and args.no_indirect:
        raise PrtError("render: --indirect-only and --no-indirect exclude each other")
    mode = "indirect" if args.indirect_only else "direct" if args.no_indirect else "full"
    from prtcore.core.raytrace import RayTracer
    from prtcore.emitters.lightfile import load_light_file
    from prtcore.io.bundle import is_hair_mesh

    manifest = read_manifest(Path(args.bundle))
    if "strands" in manifest:  # hair: the fibre tubes
        from prtcore.reference.camera import load_camera
        from prtcore.runtime.gl import write_render

        lights, camera = load_light_file(args.light), load_camera(args.camera)
        if args.cpu:
            from prtcore.runtime.strands import render_strands

            image = render_strands(args.bundle, lights, camera, n=args.basis, mode=mode)
            label = "the CPU (hair: fibre tubes ray traced, strand texture sampled" + (
                "; the mesh's lightmap sampled)" if is_hair_mesh(manifest) else ")")
        else:
            from prtcore.runtime.hair_mesh_gl import HairMeshRenderer
            from prtcore.runtime.strands_gl import render_strands_gl

            both = is_hair_mesh(manifest)
            res, label = render_strands_gl(args.bundle, lights, camera, n=args.basis,
                                           mode=mode,
                                           shadow_resolution=args.shadow_resolution,
                                           renderer=HairMeshRenderer if both else None)
            image = res.image
            label += (" (hair + mesh: the mesh's lightmap and the fibre tubes' strand "
                      "texture blended, one shadow atlas of both)" if both else
                      " (hair: fibre tubes, shadow maps, strand texture blended)")
        write_render(args.out, image, args.exposure)
        print(f"rendered: {args.out} ({image.shape[1]}×{image.shape[0]}, {mode}) on {label}")
        return 0
    if args.cpu:
        raise PrtError("render: --cpu: only hair bundles are drawn on the CPU")

    _, data, scene, _ = _posed_runtime("render", Path(args.bundle), args.time)
    lights = load_light_file(args.light)
    _warn_family("render", data, lights, RayTracer(scene.positions, scene.faces, scene.radius))
    res, label = render_to_file(args.bundle, args.light, args.camera, args.out,
                                n=args.basis, mode=mode, exposure=args.exposure,
                                shadow_resolution=args.shadow_resolution, time=args.time)
    times = ", ".join(f"{k} {v:.2f} ms" for k, v in res.wall_milliseconds.items())
    print(f"rendered: {args.out} ({res.image.shape[1]}×{res.image.shape[0]}, {mode}) on "
          f"{label}; first frame, wall clock per pass: {times}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from prtcore.viewer.server import ViewerServer

    server = ViewerServer(Path(args.bundle), port=args.port, quiet=args.quiet,
                          reference=args.reference, reference_light=args.light)
    print(f"viewer: {server.url} (Ctrl-C stops)", flush=True)
    if not args.no_browser:
        import webbrowser

        webbrowser.open(server.url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:  # Ctrl-C is how the viewer is stopped: not an error
        print("viewer: stopped", flush=True)
    finally:
        server.close()
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    import json

    from prtcore.io.bundle import read_manifest
    from prtcore.report import format_table

    bundle = Path(args.bundle)
    manifest = read_manifest(bundle)
    path = bundle / "report.json"
    if not path.is_file():
        raise PrtError(f"{bundle}: report.json is missing")
    report = json.loads(path.read_text(encoding="utf-8"))
    if manifest.get("method") == "learnt_sh":
        return _report_learnt_sh(args, bundle, report, path)
    if args.light and not args.reference_spp:
        raise PrtError("report: --light needs --reference-spp N (the path tracer's samples "
                       "per texel)")
    if args.gpu:
        from prtcore.emitters.lightfile import load_light_file
        from prtcore.report import merge_gpu_columns
        from prtcore.runtime.gl import BundleRenderer, gpu_runtime_table

        light = load_light_file(bundle / read_manifest(bundle)["validation"]
                                ["holdout_lights"])[:1]
        with BundleRenderer(bundle) as r:
            ns = [row["n"] for row in report["table"]["rows"] if row["n"] <= r.n_basis]
            merge_gpu_columns(report["table"], gpu_runtime_table(r, light, ns))
        path.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(format_table(report["table"], report.get("stage_seconds")))
    if args.reference_spp:
        from prtcore.core.progress import StageTimer
        from prtcore.validate import format_validation, validate_bundle

        v = validate_bundle(bundle, args.reference_spp, count=args.reference_lights,
                            seed=args.seed, timer=StageTimer(quiet=args.quiet),
                            light_file=args.light)
        if args.light:  # other lights than the held-out ones: kept by their file name
            report.setdefault("validation_lights", {})[Path(args.light).name] = v
        else:
            report["validation"] = v
        path.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    if report.get("validation"):
        print(format_validation(report["validation"]))
    for v in report.get("validation_lights", {}).values():
        print(format_validation(v))
    return 0


def _report_learnt_sh(args: argparse.Namespace, bundle: Path, report: dict,
                      path: Path) -> int:
    """report of a learnt_sh bundle: the bake's metrics against transfer textures
    (report.json, computed at bake time); ``--gpu`` measures the GL frame time and keeps
    it in report.json."""
    import json

    from prtcore.methods.learnt_sh import format_metrics

    if args.light or args.reference_spp:
        raise PrtError("report: --light/--reference-spp: a learnt_sh bundle is measured "
                       "against transfer textures at bake time, not the path tracer")
    metrics = report.get("metrics")
    if not metrics:
        raise PrtError(f"{bundle}: report.json has no metrics (baked with "
                       "learnt_sh.views = 0)")
    if args.gpu:
        from prtcore.methods.learnt_sh import gpu_frame_time

        report["gpu_frame"] = gpu_frame_time(bundle, metrics)
        path.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(format_metrics(metrics, report.get("gpu_frame")))
    return 0


def _add_plugin_commands(sub: argparse._SubParsersAction) -> None:
    """Subcommands provided outside the library (``serve``, ``worker``: the bake service):
    entry points of the group ``prtcore.commands``, each a callable ``register(subparsers)``
    that adds its subparser with ``set_defaults(func=...)``. The library never imports
    them; a plugin that fails to load costs only its own command."""
    from importlib.metadata import entry_points

    seen: set[str] = set()
    for ep in sorted(entry_points(group="prtcore.commands"), key=lambda e: e.name):
        if ep.name in seen or ep.name in sub.choices:
            continue
        seen.add(ep.name)
        try:
            ep.load()(sub)
        except Exception as e:  # a broken plugin must not break the library's commands
            print(f"prtcore: command {ep.name!r} unavailable ({ep.value}): "
                  f"{type(e).__name__}: {e}", file=sys.stderr)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="prtcore", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"prtcore {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bars or stage timings (CI, services)")

    sp = sub.add_parser("plan", help="the stages this asset needs and why")
    sp.add_argument("asset")
    sp.add_argument("--spec", default=None, help="bake spec JSON (defaults if omitted)")
    sp.set_defaults(func=_cmd_plan)

    sp = sub.add_parser("intake", help="load, prepare, texel space and measurement points only")
    sp.add_argument("asset")
    sp.add_argument("--spec", default=None)
    common(sp)
    sp.set_defaults(func=_cmd_intake)

    sp = sub.add_parser("bake", help="bake an asset into a PRT bundle")
    sp.add_argument("asset")
    sp.add_argument("--spec", default=None)
    sp.add_argument("--out", required=True, help="bundle directory to write")
    sp.add_argument("--mesh", default=None,
                    help="hair assets: a glTF mesh (a head, a body) baked with the hair, "
                         "in its own lightmap (docs/hair.md)")
    sp.add_argument("--force", action="store_true", help="replace an existing bundle")
    sp.add_argument("--allow-poor", action="store_true",
                    help="exit 0 even when the verdict fails (the bundle is written either "
                         "way; a failing verdict exits with status 3)")
    common(sp)
    sp.set_defaults(func=_cmd_bake)

    def runtime_args(sp: argparse.ArgumentParser, out_help: str) -> None:
        """The options relight and render share: the bundle, the lights, the output, the
        keyframe time and the basis count."""
        sp.add_argument("bundle", help="bundle directory")
        sp.add_argument("--light", required=True, help="light file (docs/lights.md)")
        sp.add_argument("--out", required=True, help=out_help)
        sp.add_argument("--time", type=float, default=None,
                        help="keyframe bundles: seconds into the animation (nearest "
                             "keyframe; default the first; outside the animation: the "
                             "nearest keyframe with a warning)")
        sp.add_argument("--basis", type=int, default=None,
                        help="basis elements to use, mean included (default: all)")

    sp = sub.add_parser("relight", help="runtime algorithm on the CPU from a bundle")
    runtime_args(sp, "output .exr (RGBA float, atlas size)")
    sp.set_defaults(func=_cmd_relight)

    sp = sub.add_parser("report", help="error against run time of a bundle")
    sp.add_argument("bundle", help="bundle directory")
    sp.add_argument("--reference-spp", type=int, default=0,
                    help="also validate held-out lights against the path tracer at N spp "
                         "(stored in report.json)")
    sp.add_argument("--reference-lights", type=int, default=None,
                    help="how many held-out lights to path-trace (default: all)")
    sp.add_argument("--light", default=None,
                    help="with --reference-spp: validate the lights of this file "
                         "(docs/lights.md) instead of the held-out ones, e.g. another light family")
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--gpu", action="store_true",
                    help="also time the GPU runtime (GL timer queries, EGL) for the table's "
                         "n that the bundle has (stored in report.json)")
    common(sp)
    sp.set_defaults(func=_cmd_report)

    sp = sub.add_parser("render", help="headless OpenGL render of a bundle (EGL)")
    runtime_args(sp, "output .png (tone-mapped) or .exr (linear)")
    sp.add_argument("--camera", required=True, help="camera file (docs/lights.md)")
    sp.add_argument("--indirect-only", action="store_true", help="indirect term only")
    sp.add_argument("--no-indirect", action="store_true",
                    help="direct light with shadows only (for comparison)")
    sp.add_argument("--exposure", type=float, default=1.0, help="PNG only: linear scale")
    sp.add_argument("--shadow-resolution", type=int, default=1024,
                    help="side of each shadow-map view")
    sp.add_argument("--cpu", action="store_true",
                    help="hair bundles (and hair + mesh bundles): ray trace the fibre "
                         "tubes (and the mesh) on the CPU instead")
    sp.set_defaults(func=_cmd_render)

    sp = sub.add_parser("view", help="the web viewer of a bundle on 127.0.0.1 (WebGL2)")
    sp.add_argument("bundle", help="bundle directory")
    sp.add_argument("--port", type=int, default=8019, help="port (0: any free port)")
    sp.add_argument("--no-browser", action="store_true",
                    help="print the URL only; do not open a browser")
    sp.add_argument("--reference", default=None,
                    help="a path-traced indirect lightmap of the bundle (`prtcore reference "
                         "DIR --light L --out REF.exr`): the page's error heat map")
    sp.add_argument("--light", default=None, help="with --reference: the light file it was "
                                                  "traced for (the page starts with it)")
    common(sp)
    sp.set_defaults(func=_cmd_view)

    sp = sub.add_parser("reference", help="indirect lightmap by the independent path tracer")
    sp.add_argument("source", help="asset file or bundle directory")
    sp.add_argument("--light", required=True, help="light file (docs/lights.md)")
    sp.add_argument("--out", required=True, help="output .exr")
    sp.add_argument("--spp", type=int, default=256)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--spec", default=None, help="spec for an asset (atlas size etc.)")
    sp.add_argument("--camera", default=None,
                    help="camera JSON: path-trace this view (direct + indirect, per pixel) "
                         "instead of the lightmap; --spp is then paths per pixel")
    sp.add_argument("--indirect-only", action="store_true", help="with --camera")
    sp.add_argument("--no-indirect", action="store_true", help="with --camera: direct only")
    common(sp)
    sp.set_defaults(func=_cmd_reference)

    sp = sub.add_parser("compare", help="data-driven PRT vs per-vertex SH-PRT vs transfer "
                                           "textures against the path tracer (table + strip)")
    sp.add_argument("asset", nargs="?", default=None,
                    help="asset (default: the project's floor-and-object scene, lit by a "
                         "directional light)")
    sp.add_argument("--out", required=True, help="output directory")
    sp.add_argument("--spec", default=None, help="bake spec for an asset")
    sp.add_argument("--spp", type=int, default=64, help="reference paths per pixel")
    sp.add_argument("--bands", type=int, default=5, help="SH bands (5: 25 coefficients)")
    sp.add_argument("--strata", type=int, default=16,
                    help="SH-PRT rays per sample = strata²")
    sp.add_argument("--lights", type=int, default=3, help="held-out lights")
    sp.add_argument("--seed", type=int, default=0)
    common(sp)
    sp.set_defaults(func=_cmd_compare)

    _add_plugin_commands(sub)
    return p


def _version() -> str:
    from prtcore import __version__
    return __version__


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except PrtError as e:
        print(f"prtcore {args.command}: error: {e}", file=sys.stderr)
        return e.exit_status
    except BrokenPipeError:  # e.g. `prtcore report DIR | head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print(f"prtcore {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
