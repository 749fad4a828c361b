"""Where quadwind_trl keeps what it can rebuild (compiled steps, PD's validation flights).

One root for every cache, so that a user moves or clears them all in one place:
``$QUADWIND_TRL_CACHE_DIR``, else ``quadwind_trl`` in the user's cache directory
(``$XDG_CACHE_HOME``, else ``~/.cache``). Nothing under it is a result: deleting it costs time only.
"""
from __future__ import annotations

import os
from pathlib import Path

# the environment variable that moves the cache root
CACHE_DIR_VARIABLE = "QUADWIND_TRL_CACHE_DIR"


def cache_dir() -> Path:
    """The root of quadwind_trl's caches (see the module docstring); not made here."""
    if os.environ.get(CACHE_DIR_VARIABLE):
        return Path(os.environ[CACHE_DIR_VARIABLE]).expanduser().absolute()
    return (Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "quadwind_trl").expanduser().absolute()
