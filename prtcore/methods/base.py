"""The method interface: what turns a transport dataset into a bundle an engine can use.

A method owns its fit, the files and manifest sections it writes, and its runtime; the
manifest's ``method`` key names it, and an engine reads that key first. The pipeline
never branches on a method's name: it asks :func:`method`.

Members register themselves (``@register``) and are imported by ``prtcore.methods``
(one line each): data-driven PRT (:mod:`prtcore.methods.data_driven`), classic SH-PRT and
transfer textures (:mod:`prtcore.methods.sh_prt`), learnt SH transfer
(:mod:`prtcore.methods.learnt_sh`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from prtcore.core.progress import StageTimer
from prtcore.core.registry import Registry
from prtcore.core.scene import Light
from prtcore.core.spec import BakeSpec


@dataclass(frozen=True, eq=False)
class BakeInputs:
    """What every method fits from.

    intake : the pipeline's IntakeResult (scene, texels, points, plan, prepare)
    train, hold : the training and held-out lights; keyframes : the KeyframeSet or None
    data : the transport Dataset (direct at points and indirect per texel for train + hold)
    indirect : None, or the training and held-out lightmaps ((T, K, 3), (T, H, 3) float32)
        as the fit sees them (denoised), when automatic sizing already prepared them
    sizing : None, or what automatic sizing chose and why (:mod:`prtcore.sizing`), as JSON
        data for the manifest and the report
    """

    spec: BakeSpec
    intake: Any
    train: tuple[Light, ...]
    hold: tuple[Light, ...]
    keyframes: Any
    data: Any
    indirect: Any = None
    sizing: dict | None = None
    #: None, or (model, full) already fitted by automatic sizing on exactly these inputs
    #: (:func:`prtcore.report.fit_for_table`)
    models: Any = None
    #: None, or the filter of ``spec.fit.denoise`` already built (T × T CSR: the noise
    #: stage's, :class:`prtcore.transport.noise.TransportNoise`)
    denoise_operator: Any = None


class Method:
    """One kind of precomputed transfer."""

    name: ClassVar[str]
    #: the method fits from the light-transport dataset (``BakeInputs.data``); when False
    #: the pipeline skips the transport stages and ``data`` is None
    needs_dataset: ClassVar[bool] = True
    #: ``validate.reference_spp`` > 0 path-traces the bundle's held-out lights
    #: (:func:`prtcore.validate.validate_bundle`, data-driven runtime data)
    path_traced_validation: ClassVar[bool] = True

    def fit(self, inputs: BakeInputs, timer: StageTimer) -> Any:
        """Fit the model (timed stages "fit" and "report"); returns the method's result."""
        raise NotImplementedError

    def write(self, directory: Path, inputs: BakeInputs, result: Any) -> tuple[dict, dict]:
        """Write the method's files into ``directory``. Returns (manifest sections, report
        fields): the sections the method owns (e.g. basis, fit, transfer, points,
        keyframes, runtime, diagnostics, metrics, validation) and its part of report.json.
        """
        raise NotImplementedError

    def summary(self, result: Any, seconds: dict[str, float], with_verdict: bool = True
                ) -> str:
        """The text written to report.txt (and printed at the end of a bake, where the
        command line prints the verdict itself, as the last line)."""
        raise NotImplementedError

    def verdict(self, result: Any) -> dict[str, Any]:
        """The bake's verdict (:func:`prtcore.verdict.judge` output)."""
        raise NotImplementedError

    def revalidate(self, result: Any, inputs: BakeInputs, validation: dict) -> Any:
        """The result with its verdict judged against a path-traced validation
        (:func:`prtcore.validate.validate_bundle` output) instead of the fast transport."""
        raise NotImplementedError

    def plot(self, result: Any, path: Path) -> None:
        """The report's figure (report.png)."""
        raise NotImplementedError


class DirectMethod(Method):
    """A method that ray-traces its own transfer (sh_prt, learnt_sh): no light dataset,
    no held-out lights, so no path-traced validation of them."""

    needs_dataset = False
    path_traced_validation = False

    def revalidate(self, result: Any, inputs: BakeInputs, validation: dict) -> Any:
        return result


_REGISTRY: Registry[Method] = Registry("method", "name")

#: class decorator: register a method under its ``name``
register = _REGISTRY.register
#: the registered method called ``name`` (KeyError names the known ones)
method = _REGISTRY.get
