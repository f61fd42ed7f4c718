"""Methods: data-driven PRT today (:mod:`~prtcore.methods.data_driven`); each registers
itself when imported below (one line per member)."""

from prtcore.methods import data_driven  # noqa: F401  (registration)
