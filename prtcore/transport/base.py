"""The transport-operator interface: what the solver needs from an operator, and the
registry.

A transport operator is one way light travels from receiver to receiver. It is traced
once per geometry, before any light is known, and yields a linear operator on receiver
values (:class:`TransportTerm`): the solver (:func:`prtcore.transport.dataset.bake_dataset`)
runs over a list of operators, adds their matrices into one operator A
(:func:`prtcore.transport.dataset.operator_matrix`) and solves
``(I − Aρ) L_ind = Aρ L_d`` for every lighting configuration at once
(:func:`prtcore.transport.solve.solve_indirect`). Each operator states its peak memory
(:meth:`TransportOperator.estimate_bytes`), which the bake's memory check adds up before
anything is allocated (:func:`prtcore.transport.dataset.check_bake_memory`).

Members today: ``"surface"``, the surface inter-reflection gather
(:mod:`prtcore.transport.surface`), and ``"subsurface"``, the random walks through the
media of translucent materials (:mod:`prtcore.transport.subsurface`, docs/subsurface.md;
the scene's materials choose it, :func:`prtcore.transport.dataset.operators_for`). Each
member is a module of this package that defines a subclass and registers it with
:func:`register`; ``prtcore.transport`` imports the members (one line each).

Where the next one plugs in: the **subsurface random walk** is
``prtcore/transport/subsurface.py`` — a ``SubsurfaceWalk(TransportOperator)`` with
``name = "subsurface"``, whose :meth:`~TransportOperator.build` walks inside the
translucent meshes from every texel and returns a term whose ``matrix`` (T, T) carries
light entering at one texel to the texels it leaves from (in the same units as the gather:
rows receive, columns are the source texels' values before albedo), whose
:meth:`~TransportOperator.estimate_bytes` counts its walks, plus one import line in
``prtcore/transport/__init__.py`` and its name in the operator list passed to
:func:`~prtcore.transport.dataset.bake_dataset` (``DEFAULT_OPERATORS`` until the spec or
the scene's materials choose).
"""

from __future__ import annotations

from typing import ClassVar, Protocol

import numpy as np
import scipy.sparse as sp

from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.core.spec import TransportSpec
from prtcore.receivers.base import Receiver

_REGISTRY: dict[str, TransportOperator] = {}


class TransportTerm(Protocol):
    """What :meth:`TransportOperator.build` returns: one linear operator on receiver values.

    matrix : (T, T) float32 CSR, rows = receiving texel, columns sorted: the light one
        bounce of this operator brings to each receiver from the values ρ·L at the sources
        (the solver applies the clamped albedo ρ)
    stats : what tracing it counted (rays, misses, …), reported under the operator's
        ``stats_key``
    channel_matrices : optional, three (T, T) float32 CSR added to ``matrix`` for the R, G
        and B channels — an operator whose light differs per channel (the subsurface
        walks, whose ``matrix`` is then empty); the solver sums them over the terms
        (:func:`prtcore.transport.dataset.channel_matrices`)
    """

    @property
    def matrix(self) -> sp.csr_matrix: ...

    @property
    def stats(self) -> dict: ...


class TransportOperator:
    """One kind of light transport between receivers. Stateless: everything it learns is
    in the :class:`TransportTerm` its :meth:`build` returns.

    name : the registry key; stage : the timed stage its :meth:`build` runs as (one of
    :data:`prtcore.transport.dataset.STAGES`); stats_key : where the dataset's stats hold
    its term's stats and the rays it traced.
    """

    name: ClassVar[str]
    stage: ClassVar[str]
    stats_key: ClassVar[str]
    #: its terms carry ``channel_matrices`` (one matrix per colour channel): the solve then
    #: iterates at full resolution (no coarse grid)
    per_channel: ClassVar[bool] = False

    def build(self, scene: Scene, receiver: Receiver, tracer: RayTracer,
              spec: TransportSpec, timer: StageTimer | None = None) -> TransportTerm:
        """Trace the operator once for this geometry (timed as ``stage`` on ``timer``).
        receiver : the elements light is gathered at (:mod:`prtcore.receivers.base`); an
        operator may need one kind (the surface gather maps hits through TEXCOORD_1, so it
        takes a :class:`~prtcore.receivers.texels.TexelSpace`)."""
        raise NotImplementedError

    def estimate_bytes(self, receivers: int, configurations: int,
                       spec: TransportSpec) -> int:
        """Peak bytes :meth:`build` and its term add to a bake of ``receivers`` receiver
        elements (covered texels) and ``configurations`` lights (an overestimate, like the
        bake's model)."""
        raise NotImplementedError

    def direct_position(self, term: TransportTerm) -> np.ndarray | None:
        """(T, J, 3) float64 points whose direct light, averaged, is each receiver's, when
        tracing the operator learnt better ones than the receiver's own sample (visible
        jittered origins); None: no opinion."""
        return None

    def first_bounce(self, term: TransportTerm, scene: Scene, tracer: RayTracer,
                     lights: tuple[Light, ...], direct: np.ndarray, timer: StageTimer
                     ) -> tuple[np.ndarray, np.ndarray] | None:
        """A correction of the first bounce ``A L_d`` for ``direct`` (T, K, 3) at the
        receivers: rows (r,) int64 sorted unique and values (r, K, 3) float32 added there
        (:func:`prtcore.transport.solve.solve_indirect`'s ``first_bounce``); None: none."""
        return None


def register(cls: type[TransportOperator]) -> type[TransportOperator]:
    """Class decorator: make ``cls`` the operator named ``cls.name``."""
    if cls.name in _REGISTRY:
        raise ValueError(f"transport operator {cls.name!r} registered twice")
    _REGISTRY[cls.name] = cls()
    return cls


def operator_for(name: str) -> TransportOperator:
    """The registered operator called ``name``. KeyError names the known ones."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"no transport operator {name!r} (known: {', '.join(names())})"
                       ) from None


def names() -> tuple[str, ...]:
    """Registered operator names, in registration order."""
    return tuple(_REGISTRY)
