"""Emitters: the kinds of light a bake is trained on and relit with.

:mod:`prtcore.emitters.base` is the interface and registry; each member registers itself
when imported below (one line per member). :mod:`~prtcore.emitters.punctual` is the one
light evaluation, :mod:`~prtcore.emitters.lightfile` the light-file contract and
:mod:`~prtcore.emitters.families` the random families of the bake spec.
"""

from prtcore.emitters import directional, environment_light, point, spot  # noqa: F401  (registration)
