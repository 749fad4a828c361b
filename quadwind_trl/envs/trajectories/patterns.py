"""The built-in patterns: the paper's horizontal and vertical libraries, and ``hover``.

They are registered here, in this order, so that their integer ids (0-9) are the ones stored in
every dataset and result made before the registry existed; new patterns (user code) come after.
Sizes and speeds are :class:`~quadwind_trl.config.TrajectoryConfig` fields (docs/simulator.md).
"""
from __future__ import annotations

from torch import Tensor

from .base import ClimbingPattern, LevelPattern, register_trajectory, registered_patterns
from .paths import circle, lemniscate, raster, rose, stadium, still


@register_trajectory("loiter_circle_h")
class LoiterCircle(LevelPattern):
    def path(self, s: Tensor) -> Tensor:
        return circle(s, self.cfg.loiter_radius_m)


@register_trajectory("racetrack_h")
class Racetrack(LevelPattern):
    def path(self, s: Tensor) -> Tensor:
        return stadium(s, self.cfg.racetrack_straight_m, self.cfg.racetrack_radius_m)


@register_trajectory("figure8_h")
class Figure8(LevelPattern):
    by_phase = True

    def path(self, s: Tensor) -> Tensor:
        return lemniscate(s, self.cfg.figure8_half_length_m)


@register_trajectory("cloverleaf_h")
class Cloverleaf(LevelPattern):
    by_phase = True

    def path(self, s: Tensor) -> Tensor:
        return rose(s, self.cfg.cloverleaf_radius_m)


@register_trajectory("lawnmower_h")
class Lawnmower(LevelPattern):
    def path(self, s: Tensor) -> Tensor:
        return raster(s, self.cfg.lawnmower_leg_m, self.cfg.lawnmower_spacing_m, self.cfg.lawnmower_legs)


# the paper's two libraries, by name
HORIZONTAL = ("loiter_circle_h", "racetrack_h", "figure8_h", "cloverleaf_h", "lawnmower_h")
VERTICAL = ("vertical_climb", "spiral_ascent", "figure8_3d", "lawnmower_scan")
HOVER = "hover"


class _PaperClimb(ClimbingPattern):
    """The paper's vertical patterns: each climbs at its entry of
    ``TrajectoryConfig.vertical_climb_rate_m_s``, which lists them in ``VERTICAL`` order."""

    @property
    def climb_rate(self) -> float:
        names = {cls: name for name, cls in registered_patterns().items()}
        # the paper pattern this class is (or derives from: a user subclass keeps its rate)
        name = next(names[cls] for cls in type(self).__mro__ if names.get(cls) in VERTICAL)
        return self.cfg.vertical_climb_rate_m_s[VERTICAL.index(name)]


@register_trajectory("vertical_climb")
class VerticalClimb(_PaperClimb):
    speed = 0.0  # straight up: no horizontal motion

    def path(self, s: Tensor) -> Tensor:
        return still(s)


@register_trajectory("spiral_ascent")
class SpiralAscent(_PaperClimb):
    def path(self, s: Tensor) -> Tensor:
        return circle(s, self.cfg.spiral_radius_m)


@register_trajectory("figure8_3d")
class Figure8Climb(_PaperClimb):
    by_phase = True

    def path(self, s: Tensor) -> Tensor:
        return lemniscate(s, self.cfg.figure8_3d_half_length_m)


@register_trajectory("lawnmower_scan")
class LawnmowerScan(_PaperClimb):
    def path(self, s: Tensor) -> Tensor:
        return raster(s, self.cfg.scan_leg_m, self.cfg.scan_spacing_m, self.cfg.scan_legs)


@register_trajectory("hover")
class Hover(LevelPattern):
    """Station keeping at the episode's altitude: not in the paper's libraries; for tests and users."""

    speed = 0.0

    @property
    def duration(self) -> float:
        return self.cfg.hover_duration_s

    def path(self, s: Tensor) -> Tensor:
        return still(s)

