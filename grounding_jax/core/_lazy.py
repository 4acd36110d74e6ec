"""Public names imported on first use (PEP 562), so that importing a package stays light: a
command-line tool can take over SIGINT before JAX loads."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_names(package: str, names: dict[str, str], namespace: dict[str, Any]
               ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """A package's ``__getattr__`` and ``__dir__`` for ``names`` (name -> module holding it).

    Args:
        package: the package's name, for the error message.
        names: each public name and the module it is imported from on first use.
        namespace: the package's ``globals()`` (a name, once imported, is kept there).
    """
    def getattr_(name: str) -> Any:
        if name in names:
            value = getattr(importlib.import_module(names[name]), name)
            namespace[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def dir_() -> list[str]:
        return sorted(set(namespace) | set(names))

    return getattr_, dir_
