"""prtcore: a baker of data-driven Precomputed Radiance Transfer (Belcour et al. 2022).

The public API: the names below are what the CLI, the service and the workers use, and
what a pipeline script should use. They resolve lazily, so ``import prtcore`` stays light
(the service's API process imports it without loading Embree or OpenGL).

Layout (docs/architecture.md): ``core`` (scene, spec, errors, limits, tolerances,
progress) → ``io`` (glTF, images, bundle) → ``intake`` (plan, prepare, measurement points)
→ ``receivers`` (texel space) → ``emitters`` (lights) → ``transport`` → ``fit`` →
``methods`` → ``runtime`` → ``pipeline``/``report``/``validate`` → ``cli``.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name → module that defines it
_PUBLIC = {
    # errors and limits
    "PrtError": "prtcore.core.errors",
    "AssetError": "prtcore.core.errors",
    "SpecError": "prtcore.core.errors",
    "LimitExceeded": "prtcore.core.errors",
    "LightFileError": "prtcore.core.errors",
    "BundleError": "prtcore.core.errors",
    "TransportDiverged": "prtcore.core.errors",
    "IntakeLimits": "prtcore.core.limits",
    "StageTimer": "prtcore.core.progress",
    # spec
    "BakeSpec": "prtcore.core.spec",
    "parse_spec": "prtcore.core.spec",
    "load_spec": "prtcore.core.spec",
    "spec_hash": "prtcore.core.spec",
    "spec_to_dict": "prtcore.core.spec",
    "canonical_spec_json": "prtcore.core.spec",
    # intake
    "load_asset": "prtcore.io.gltf.loader",
    "load_hair": "prtcore.io.hair",
    "is_hair_file": "prtcore.io.hair",
    "plan_asset": "prtcore.intake.plan",
    "run_intake": "prtcore.pipeline",
    # bake and bundle
    "bake": "prtcore.pipeline",
    "STAGES": "prtcore.pipeline",
    "read_manifest": "prtcore.io.bundle",
    "load_runtime": "prtcore.io.bundle",
    "is_bundle": "prtcore.io.bundle",
    "load_light_file": "prtcore.emitters.lightfile",
    "relight": "prtcore.runtime.cpu",
    # the web viewer (package data: page and static files)
    "viewer_page": "prtcore.viewer.page",
    "viewer_static_path": "prtcore.viewer.page",
    "viewer_content_type": "prtcore.viewer.page",
}

__all__ = ["__version__", *sorted(_PUBLIC)]


def __getattr__(name: str) -> Any:
    try:
        module = _PUBLIC[name]
    except KeyError:
        raise AttributeError(f"module 'prtcore' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
