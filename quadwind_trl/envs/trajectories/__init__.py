"""Trajectories: one class per pattern (:mod:`.base` is the template and the registry), the
built-in patterns (:mod:`.patterns`), the planar paths they are made of (:mod:`.paths`) and the
library that tabulates every registered pattern for the batched simulator (:mod:`.library`).

Add a pattern in user code: subclass :class:`LevelPattern` (or :class:`ClimbingPattern`), give
it a ``path(s)``, and register it with :func:`register_trajectory` before building an env.
"""
from .base import (
    ClimbingPattern,
    LevelPattern,
    Pattern,
    fixed_altitude_mask,
    register_trajectory,
    registered_patterns,
    trajectory_id,
    trajectory_ids,
    trajectory_name,
    trajectory_names,
)
from .library import Reference, TrajectoryLibrary
from .patterns import HORIZONTAL, HOVER, VERTICAL
from .profiles import climb_profile, ramp_integral, smoothstep

__all__ = [
    "Pattern",
    "LevelPattern",
    "ClimbingPattern",
    "register_trajectory",
    "registered_patterns",
    "trajectory_names",
    "trajectory_name",
    "trajectory_id",
    "trajectory_ids",
    "fixed_altitude_mask",
    "TrajectoryLibrary",
    "Reference",
    "HORIZONTAL",
    "VERTICAL",
    "HOVER",
    "climb_profile",
    "ramp_integral",
    "smoothstep",
]
