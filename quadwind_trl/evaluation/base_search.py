"""Moved to :mod:`quadwind_trl.studies.base_search` (the project's studies); this path warns, and goes in
the next release."""
from ._moved import moved

__getattr__ = moved(__name__, "quadwind_trl.studies.base_search")
