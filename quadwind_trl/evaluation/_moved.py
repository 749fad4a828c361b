"""Names that moved from the library's evaluation to :mod:`quadwind_trl.studies`: the old import
paths keep working for one release, with a ``DeprecationWarning`` naming the new home."""
from __future__ import annotations

import importlib
import warnings
from typing import Any, Callable, Mapping


def moved(old: str, homes: Mapping[str, str] | str) -> Callable[[str], Any]:
    """A module ``__getattr__`` for module ``old``: each name of ``homes`` (name -> the module it
    moved to; a module name alone: every name that module has) is fetched from its new home with
    a ``DeprecationWarning``; any other name is an ``AttributeError``."""

    def __getattr__(name: str) -> Any:
        home = homes if isinstance(homes, str) else homes.get(name)
        if home is not None and not name.startswith("__"):
            module = importlib.import_module(home)
            if hasattr(module, name):
                warnings.warn(f"{old}.{name} has moved to {home}.{name}: import it from there "
                              f"({old} stops providing it in the next release)", DeprecationWarning, stacklevel=2)
                return getattr(module, name)
        raise AttributeError(f"module {old!r} has no attribute {name!r}")

    return __getattr__
