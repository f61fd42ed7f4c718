"""Methods: data-driven PRT (:mod:`~prtcore.methods.data_driven`) and classic SH-PRT /
transfer textures (:mod:`~prtcore.methods.sh_prt`); each registers
itself when imported below (one line per member)."""

from prtcore.methods import data_driven, sh_prt  # noqa: F401  (registration)
