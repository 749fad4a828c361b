"""What a trajectory pattern provides (the template), and the registry of patterns by name.

A pattern is one class: a closed-form planar path ``P(s)`` (by arc length in metres, or by
phase in radians with ``by_phase = True``), the horizontal speed it is flown at, its duration
and, for a pattern that climbs as it flies, the climb rate and the altitude it climbs to. The
library differentiates ``P`` exactly and tabulates the reference at the control instants
(:mod:`.library`); a pattern never writes a derivative by hand.

Two kinds, by what happens before the pattern starts:

* :class:`LevelPattern`: flown at the episode's own altitude (scenario field ``altitude_m``),
  after an analytic climb there; the paper's horizontal library and ``hover``.
* :class:`ClimbingPattern`: climbs from the ground to ``TrajectoryConfig.vertical_top_m`` while
  flying the path (the climb is part of the pattern); the paper's vertical library.

Adding a pattern, in user code (the library is not edited)::

    from quadwind_trl.envs.trajectories import LevelPattern, register_trajectory

    @register_trajectory("my_pattern")
    class MyPattern(LevelPattern):
        def path(self, s):  # s: 0-d float64 tensor (m along the path); returns [2] (x east, y north) m
            return torch.stack((s, 0 * s))

Ids: a scenario carries the integer ``traj_id`` (a batched gather needs an integer); it is the
pattern's position in registration order. The built-in patterns are registered first, always in
the same order, so their ids never change; anything persisted (dataset manifests, result tables)
stores names or a name -> id map, never a bare position.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from operator import attrgetter
from typing import Callable, ClassVar, Sequence

import torch
from torch import Tensor

from ...config import TrajectoryConfig


class Pattern(ABC):
    """The template of a trajectory pattern (one subclass per pattern).

    A subclass provides :meth:`path` and, unless it inherits them from :class:`LevelPattern` or
    :class:`ClimbingPattern`, ``speed`` and ``duration`` (properties, :func:`config_field` for a
    config field, or class attributes when constant). Sizes come from ``self.cfg`` (a
    :class:`~quadwind_trl.config.TrajectoryConfig`) or from class attributes.
    """

    by_phase: ClassVar[bool] = False  # progress s is a phase (rad) rather than an arc length (m)
    climbs: ClassVar[bool] = False  # True: the pattern climbs itself; False: flown at the episode's altitude

    def __init__(self, cfg: TrajectoryConfig):
        self.cfg = cfg

    @abstractmethod
    def path(self, s: Tensor) -> Tensor:
        """Planar position ``[2]`` (x east, y north; m) at progress ``s`` (a 0-d float64 tensor),
        in torch operations only: it is differentiated by forward-mode autodiff and vmapped."""

    @property
    @abstractmethod
    def speed(self) -> float:
        """Horizontal speed, m/s: constant along an arc-length path, the maximum along a phase path."""

    @property
    @abstractmethod
    def duration(self) -> float:
        """Seconds from the pattern's start to the end of the flight."""

    @property
    def climb_rate(self) -> float:
        """Climb rate, m/s, of a climbing pattern (0 for level ones)."""
        return 0.0

    @property
    def climb_to(self) -> float:
        """Altitude, m, a climbing pattern climbs to (0 for level ones)."""
        return 0.0


def config_field(name: str, doc: str | None = None) -> property:
    """A read-only property of a pattern: the field ``name`` of its ``TrajectoryConfig``."""
    return property(attrgetter(f"cfg.{name}"), doc=doc)


class LevelPattern(Pattern):
    """A pattern flown at the episode's altitude, at cruise speed for ``horizontal_duration_s``."""

    speed = config_field("cruise_speed_m_s")
    duration = config_field("horizontal_duration_s", "The pattern only: the climb to the episode's altitude "
                                                     "comes before it (run-time analytic).")


class ClimbingPattern(Pattern):
    """A pattern that climbs to ``vertical_top_m`` at :attr:`climb_rate` as it flies, then hovers
    there for ``vertical_hold_s``; horizontal speed ``vertical_speed_m_s``."""

    climbs = True

    @property
    @abstractmethod
    def climb_rate(self) -> float: ...

    climb_to = config_field("vertical_top_m")
    speed = config_field("vertical_speed_m_s")

    @property
    def duration(self) -> float:
        """The climb at its rate, the blend that ends it, then the hold at the top."""
        return self.cfg.vertical_top_m / self.climb_rate + self.cfg.climb_blend_s + self.cfg.vertical_hold_s


_REGISTRY: dict[str, type[Pattern]] = {}


def register_trajectory(name: str, pattern: type[Pattern] | None = None) -> Callable | type[Pattern]:
    """Register ``pattern`` (a :class:`Pattern` subclass) under ``name``; also a class decorator.

    The new pattern gets the next integer id. Registering the same class again under its name is
    a no-op (a re-run script); another class under a taken name is refused."""

    def add(cls: type[Pattern]) -> type[Pattern]:
        if not isinstance(name, str) or not name:
            raise ValueError(f"register_trajectory: name={name!r}; allowed: a non-empty string")
        if not (isinstance(cls, type) and issubclass(cls, Pattern)) or getattr(cls, "__abstractmethods__", None):
            raise TypeError(f"register_trajectory({name!r}): {cls!r} is not a concrete subclass of Pattern "
                            "(it must define path, speed and duration)")
        taken = _REGISTRY.get(name)
        if taken is not None and taken is not cls:
            raise ValueError(f"register_trajectory: name {name!r} is taken by {taken.__qualname__}; "
                             f"registered: {', '.join(_REGISTRY)}")
        _REGISTRY[name] = cls
        return cls

    return add if pattern is None else add(pattern)


def registered_patterns() -> dict[str, type[Pattern]]:
    """Name -> pattern class, in id order (a copy)."""
    return dict(_REGISTRY)


def trajectory_names() -> tuple[str, ...]:
    """The registered names; a name's position is its ``traj_id``."""
    return tuple(_REGISTRY)


def trajectory_name(traj_id: int) -> str:
    """The name of a registered ``traj_id``."""
    names = trajectory_names()
    allowed = f"0-{len(names) - 1} ({', '.join(names)})"
    try:
        index = int(traj_id)  # a Python or numpy int, a 0-d tensor, a table's entry
    except (TypeError, ValueError):
        raise TypeError(f"traj_id={traj_id!r}: expected an integer id; allowed: {allowed}") from None
    if not 0 <= index < len(names):
        raise ValueError(f"traj_id={traj_id} is not registered; allowed: {allowed}")
    return names[index]


def trajectory_id(name: str) -> int:
    """The id of a registered trajectory, or a ``ValueError`` listing the registered names."""
    names = trajectory_names()
    if name not in names:
        raise ValueError(f"traj_id={name!r} is not a registered trajectory; registered: {', '.join(names)}")
    return names.index(name)


def trajectory_ids(names: Sequence[str], device: torch.device | str | None = None) -> Tensor:
    """``[len(names)]`` int64 ids of registered names (an unknown name fails, listing the registered)."""
    if isinstance(names, str):
        raise TypeError(f"trajectories={names!r}: expected a sequence of names, such as ({names!r},)")
    return torch.tensor([trajectory_id(name) for name in names], dtype=torch.int64, device=device)


def fixed_altitude_mask(device: torch.device | str | None = None) -> Tensor:
    """``[num_registered]`` bool by id: flown at the episode's own altitude (not climbing)."""
    return torch.tensor([not cls.climbs for cls in _REGISTRY.values()], dtype=torch.bool, device=device)
