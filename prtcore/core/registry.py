"""Registries of the families whose members are modules (emitters, transfer regressors,
transport operators, methods): a new member is a new module that registers its class."""

from __future__ import annotations

from typing import Generic, TypeVar

T = TypeVar("T")


class Registry(Generic[T]):
    """Name → one stateless instance of a member class.

    family : what the members are, for messages ("light type", "transfer regressor");
    key : the class attribute that names a member ("type", "name").
    """

    def __init__(self, family: str, key: str):
        self.family = family
        self.key = key
        self._members: dict[str, T] = {}

    def register(self, cls: type[T]) -> type[T]:
        """Class decorator: register one instance of ``cls`` under ``cls.<key>``."""
        name = getattr(cls, self.key)
        if name in self._members:
            raise ValueError(f"{self.family} {name!r} registered twice")
        self._members[name] = cls()
        return cls

    def get(self, name: str) -> T:
        """The member called ``name``; KeyError names the known ones."""
        try:
            return self._members[name]
        except KeyError:
            raise KeyError(f"no {self.family} {name!r} (known: {', '.join(self.names())})"
                           ) from None

    def names(self) -> tuple[str, ...]:
        """Registered names, in registration order."""
        return tuple(self._members)
