"""Methods: data-driven PRT (:mod:`~prtcore.methods.data_driven`), classic SH-PRT /
transfer textures (:mod:`~prtcore.methods.sh_prt`) and learnt SH transfer
(:mod:`~prtcore.methods.learnt_sh`); each registers
itself when imported below (one line per member)."""

from prtcore.methods import data_driven, learnt_sh, sh_prt  # noqa: F401  (registration)
