"""Typed errors. Every refusal names what is wrong and where, on one line.

The CLI turns any :class:`PrtError` into exit status 2 with ``str(error)`` as its message.
"""

from __future__ import annotations


class PrtError(Exception):
    """Base of every error prtcore raises on purpose (bad input, refused work)."""

    exit_status = 2


class AssetError(PrtError):
    """The asset cannot be used.

    Parameters
    ----------
    file : str
        Path of the asset (or external buffer/image) the problem is in.
    where : str
        glTF path of the offending element, e.g. ``meshes[2].primitives[0].attributes.POSITION``;
        ``""`` when the whole file is meant.
    what : str
        What is wrong, one short sentence without a trailing full stop.
    limit : str, optional
        The limit that was exceeded, e.g. ``max_triangles=2000000``.
    """

    def __init__(self, file: str, where: str, what: str, limit: str | None = None):
        self.file = str(file)
        self.where = where
        self.what = what
        self.limit = limit
        parts = [self.file]
        if where:
            parts.append(where)
        msg = ": ".join(parts) + ": " + what
        if limit:
            msg += f" (limit {limit})"
        super().__init__(msg.replace("\n", " "))


class LimitExceeded(AssetError):
    """The asset is larger than a configured intake limit allows (checked before allocating)."""


class UnsupportedAsset(AssetError):
    """The asset uses a feature prtcore refuses (e.g. Draco/meshopt compression)."""


class SpecError(PrtError):
    """The bake spec is invalid. ``key`` is its JSON path, e.g. ``lights.families[0].type``."""

    def __init__(self, key: str, what: str, file: str | None = None):
        self.key = key
        self.what = what
        self.file = file
        prefix = f"{file}: " if file else ""
        super().__init__(f"{prefix}spec {key}: {what}".replace("\n", " "))


class LightFileError(PrtError):
    """A light file (docs/lights.md) is invalid."""


class BundleError(PrtError):
    """A bundle directory is missing files or inconsistent with its manifest."""


class TransportDiverged(PrtError):
    """The indirect solve's series grows instead of converging: its operator, made from
    too few or too noisy rays, sends more light on than it receives."""
