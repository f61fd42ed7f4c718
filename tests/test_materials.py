"""Translucent materials (issue 15, docs/subsurface.md): the glTF extensions, the spec's
``materials`` section, the albedo inversion and the symmetric Lambertian boundary."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core.errors import SpecError
from prtcore.core.materials import (
    albedo_at,
    apply_material_spec,
    has_translucency,
    multiple_scattering_albedo,
    single_scattering_albedo,
)
from prtcore.core.spec import parse_spec
from prtcore.io.gltf.loader import load_asset


def test_inversion_of_chiang_et_al_2016_at_published_points():
    # α = 1 − exp(−5.09406 A + 2.61188 A² − 4.31805 A³), evaluated by hand at A = 0.5, 1
    a = single_scattering_albedo(np.array([0.0, 0.5, 1.0]))
    assert a[0] == 0.0
    assert a[1] == pytest.approx(1 - np.exp(-2.547030 + 0.652970 - 0.539756), rel=1e-6)
    assert a[2] == pytest.approx(1 - np.exp(-6.80023), rel=1e-6)
    assert (np.diff(single_scattering_albedo(np.linspace(0, 1, 101))) > 0).all()
    x = np.linspace(0, 0.998, 50)
    np.testing.assert_allclose(single_scattering_albedo(multiple_scattering_albedo(x)), x,
                               atol=1e-12)


def test_gltf_extensions_give_the_medium(tmp_path):
    from prtcore.scenes.translucent import write_translucent_sphere

    scene = load_asset(write_translucent_sphere(tmp_path / "s.glb", mean_free_path=[0.1, 0.2, 0.4],
                                                multiscatter=[0.8, 0.5, 0.2],
                                                anisotropy=0.3))
    skin = next(m for m in scene.materials if m.name == "skin")
    floor = next(m for m in scene.materials if m.name == "floor")
    assert floor.subsurface is None and has_translucency(scene)
    ss = skin.subsurface
    np.testing.assert_allclose(ss.sigma_t, [10.0, 5.0, 2.5], rtol=1e-12)
    np.testing.assert_allclose(ss.albedo, single_scattering_albedo([0.8, 0.5, 0.2]))
    assert ss.anisotropy == pytest.approx(0.3) and ss.transmission == 0.5
    # the boundary: ½((1 − t)·base + t·c_t) with t 0.5, c_t 0.9 (base ≈ 0.9, 8-bit)
    tri = np.flatnonzero(scene.face_material == scene.materials.index(skin))[:3]
    want = 0.5 * (0.5 * skin.base_color_factor[:3] + 0.5 * 0.9)
    np.testing.assert_allclose(albedo_at(scene, tri, np.full((3, 3), 1 / 3)),
                               np.broadcast_to(want, (3, 3)), rtol=1e-12)


def test_export_round_trips_the_medium(tmp_path):
    from prtcore.intake.prepare import prepare_scene
    from prtcore.io.gltf.export import write_glb
    from prtcore.scenes.translucent import write_translucent_sphere

    spec = parse_spec({"atlas": {"resolution": 32, "padding": 1}})
    scene, _ = prepare_scene(load_asset(write_translucent_sphere(
        tmp_path / "s.glb", mean_free_path=[0.1, 0.2, 0.4], multiscatter=[0.8, 0.5, 0.2],
        subdivisions=1)), spec)
    write_glb(scene, tmp_path / "out.glb")
    back = load_asset(tmp_path / "out.glb")
    a = next(m for m in scene.materials if m.name == "skin").subsurface
    b = next(m for m in back.materials if m.name == "skin").subsurface
    np.testing.assert_allclose(b.sigma_t, a.sigma_t, rtol=1e-12)
    np.testing.assert_allclose(b.albedo, a.albedo, rtol=1e-12)
    np.testing.assert_allclose(b.transmission_color, a.transmission_color)


def test_spec_override_makes_a_material_translucent_and_names_bad_keys(tmp_path):
    from prtcore.scenes.translucent import write_translucent_sphere

    scene = load_asset(write_translucent_sphere(tmp_path / "s.glb", subdivisions=1))
    spec = parse_spec({"materials": {"floor": {"subsurface": {
        "albedo": [0.9, 0.5, 0.3], "mean_free_path": 0.2, "anisotropy": 0.1}}}})
    out = apply_material_spec(scene, spec.materials)
    ss = next(m for m in out.materials if m.name == "floor").subsurface
    np.testing.assert_allclose(ss.sigma_t, 5.0)
    np.testing.assert_allclose(ss.albedo, single_scattering_albedo([0.9, 0.5, 0.3]))
    # spec echo parses back to the same spec
    from prtcore.core.spec import spec_to_dict
    assert parse_spec(spec_to_dict(spec)) == spec
    with pytest.raises(SpecError, match=r"materials\.nope: the asset has no material"):
        apply_material_spec(scene, parse_spec({"materials": {"nope": {}}}).materials)
    with pytest.raises(SpecError, match=r"materials\.floor: the material is opaque"):
        apply_material_spec(scene, parse_spec({"materials": {"floor": {}}}).materials)
    for bad, key in (({"skin": {"boundary": "glass"}}, "materials.skin.boundary"),
                     ({"skin": {"subsurface": {"mfp": 1}}}, "materials.skin.subsurface.mfp"),
                     ({"skin": {"subsurface": {"mean_free_path": 0}}},
                      "materials.skin.subsurface.mean_free_path")):
        with pytest.raises(SpecError, match=key.replace(".", r"\.")):
            parse_spec({"materials": bad})
