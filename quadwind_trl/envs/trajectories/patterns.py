"""The built-in patterns: the paper's horizontal and vertical libraries, and ``hover``.

They are registered here, in this order, so that their integer ids (0-9) are the ones stored in
every dataset and result made before the registry existed; new patterns (user code) come after.
Sizes and speeds are :class:`~quadwind_trl.config.TrajectoryConfig` fields (docs/simulator.md).

A pattern of the paper's libraries is a planar path of :mod:`.paths` sized by config fields, so
the libraries are tables (:data:`_HORIZONTAL`, :data:`_VERTICAL`) from which one class per
pattern is made; ``hover`` is written as a user would write a pattern.
"""
from __future__ import annotations

from typing import Callable, ClassVar

from torch import Tensor

from .base import ClimbingPattern, LevelPattern, Pattern, config_field, register_trajectory
from .paths import circle, lemniscate, raster, rose, stadium, still

# The paper's two libraries, each in id order: name -> (class name, path, the TrajectoryConfig
# fields that are the path's sizes, in its argument order).
_HORIZONTAL = {
    "loiter_circle_h": ("LoiterCircle", circle, ("loiter_radius_m",)),
    "racetrack_h": ("Racetrack", stadium, ("racetrack_straight_m", "racetrack_radius_m")),
    "figure8_h": ("Figure8", lemniscate, ("figure8_half_length_m",)),
    "cloverleaf_h": ("Cloverleaf", rose, ("cloverleaf_radius_m",)),
    "lawnmower_h": ("Lawnmower", raster, ("lawnmower_leg_m", "lawnmower_spacing_m", "lawnmower_legs")),
}
_VERTICAL = {
    "vertical_climb": ("VerticalClimb", still, ()),
    "spiral_ascent": ("SpiralAscent", circle, ("spiral_radius_m",)),
    "figure8_3d": ("Figure8Climb", lemniscate, ("figure8_3d_half_length_m",)),
    "lawnmower_scan": ("LawnmowerScan", raster, ("scan_leg_m", "scan_spacing_m", "scan_legs")),
}
_BY_PHASE = (lemniscate, rose)  # the paths of .paths whose progress is a phase (rad), not an arc length

# the paper's two libraries, by name
HORIZONTAL = tuple(_HORIZONTAL)
VERTICAL = tuple(_VERTICAL)
HOVER = "hover"


class _PaperPattern(Pattern):
    """A pattern of the paper's libraries: the path ``shape`` sized by the config fields ``sizes``."""

    shape: ClassVar[Callable[..., Tensor]]  # a path of .paths: (s, *sizes) -> [2]
    sizes: ClassVar[tuple[str, ...]]
    index: ClassVar[int]  # the pattern's position in its library

    def path(self, s: Tensor) -> Tensor:
        return self.shape(s, *(getattr(self.cfg, size) for size in self.sizes))


class _PaperClimb(_PaperPattern, ClimbingPattern):
    """The paper's vertical patterns: each climbs at its entry of
    ``TrajectoryConfig.vertical_climb_rate_m_s``, which lists them in ``VERTICAL`` order (a user
    subclass of one keeps its rate)."""

    @property
    def climb_rate(self) -> float:
        return self.cfg.vertical_climb_rate_m_s[self.index]


def _register_library(bases: tuple[type[Pattern], ...], library: dict) -> None:
    """Make one class (on ``bases``) per pattern of ``library`` and register it, in its order."""
    for index, (name, (class_name, shape, sizes)) in enumerate(library.items()):
        namespace = {"__module__": __name__, "shape": staticmethod(shape), "sizes": sizes, "index": index,
                     "by_phase": shape in _BY_PHASE}
        if shape is still:
            namespace["speed"] = 0.0  # straight up: no horizontal motion
        register_trajectory(name, type(class_name, bases, namespace))


_register_library((_PaperPattern, LevelPattern), _HORIZONTAL)
_register_library((_PaperClimb,), _VERTICAL)


@register_trajectory(HOVER)
class Hover(LevelPattern):
    """Station keeping at the episode's altitude: not in the paper's libraries; for tests and users."""

    speed = 0.0
    duration = config_field("hover_duration_s")

    def path(self, s: Tensor) -> Tensor:
        return still(s)
