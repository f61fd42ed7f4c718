"""Hair intake: cyHair ``.hair`` (:mod:`.yuksel`) and USD ``BasisCurves`` (:mod:`.usd`)
→ :class:`~prtcore.core.hair.Hair`, hardened like the glTF loader (limits before
allocation, NaN refused, one-line errors naming file and field)."""

from __future__ import annotations

from pathlib import Path

from prtcore.core.errors import UnsupportedAsset
from prtcore.core.hair import Hair
from prtcore.core.limits import IntakeLimits
from prtcore.io.hair.usd import read_usd_hair, write_usd_hair
from prtcore.io.hair.yuksel import read_hair, write_hair

#: file suffixes read as hair
HAIR_SUFFIXES = (".hair", ".usd", ".usda", ".usdc")

__all__ = ["HAIR_SUFFIXES", "is_hair_file", "load_hair", "read_hair", "read_usd_hair",
           "write_hair", "write_usd_hair"]


def is_hair_file(path: str | Path) -> bool:
    """The file's suffix names a hair format."""
    return Path(path).suffix.lower() in HAIR_SUFFIXES


def load_hair(path: str | Path, limits: IntakeLimits | None = None) -> Hair:
    """Read a hair file by its suffix (``.hair`` or ``.usd``/``.usda``/``.usdc``)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".hair":
        return read_hair(path, limits)
    if suffix in (".usd", ".usda", ".usdc"):
        return read_usd_hair(path, limits)
    raise UnsupportedAsset(str(path), "", f"{suffix!r} is not a hair format "
                           f"({', '.join(HAIR_SUFFIXES)})")
