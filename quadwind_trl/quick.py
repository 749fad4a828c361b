"""Shorter flights for the smoke runs (``--quick``): one definition of what "quick" changes in a
flight, shared by the PPO recipes (:mod:`quadwind_trl.rl.cli`) and the evaluation sweeps
(:func:`quadwind_trl.evaluation.tracking.sweep_setup`: PD baseline, ablation, error budget, replay).

A quick flight is shorter (``config``: pattern duration, climb top and hold) and starts airborne
at its pattern (``scenarios``), the fixed-altitude patterns flown low (``scenarios`` / ``ranges``)
so no second of a smoke run goes to climbing.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from tensordict import TensorDictBase

from .config import EnvConfig
from .envs.scenarios import RegimeRanges


@dataclass(frozen=True)
class QuickFlights:
    """What ``--quick`` changes in a flight; ``None`` leaves a setting as it is."""

    pattern_s: float | None = None  # s: duration of the fixed-altitude (horizontal) patterns
    vertical_top_m: float | None = None  # m: top of the vertical climbs
    vertical_hold_s: float | None = None  # s: hold at the top of a vertical climb
    altitude_m: float | None = None  # m: altitude the fixed-altitude patterns are flown at

    def config(self, cfg: EnvConfig) -> EnvConfig:
        """``cfg`` with the shorter trajectories."""
        changes = {name: value for name, value in (("horizontal_duration_s", self.pattern_s),
                                                   ("vertical_top_m", self.vertical_top_m),
                                                   ("vertical_hold_s", self.vertical_hold_s)) if value is not None}
        return replace(cfg, trajectories=replace(cfg.trajectories, **changes))

    def scenarios(self, scenarios: TensorDictBase, top_altitude_m: float) -> TensorDictBase:
        """A copy of ``scenarios`` started airborne at the pattern start, the fixed-altitude ones
        (below ``top_altitude_m``, the vertical climbs' top) at ``altitude_m``."""
        out = scenarios.clone()
        if self.altitude_m is not None:
            out["altitude_m"] = torch.where(out["altitude_m"] < top_altitude_m, self.altitude_m, out["altitude_m"])
        out["start_step"] = torch.full_like(out["start_step"], -1)
        return out

    def ranges(self, ranges: RegimeRanges) -> RegimeRanges:
        """Training scenario ranges with the fixed-altitude patterns at ``altitude_m``."""
        if self.altitude_m is None or ranges.altitude_m is None:
            return ranges
        return replace(ranges, altitude_m=(self.altitude_m, self.altitude_m))

    def describe(self) -> str:
        """One line for a recipe's ``--quick`` notice."""
        pattern = " ".join(p for p in (f"patterns {self.pattern_s:g} s" if self.pattern_s is not None else "",
                                       f"at {self.altitude_m:g} m" if self.altitude_m is not None else "") if p)
        climb = " ".join(p for p in (f"climbs to {self.vertical_top_m:g} m" if self.vertical_top_m is not None else "",
                                     f"with a {self.vertical_hold_s:g} s hold" if self.vertical_hold_s is not None else "") if p)
        return ", ".join(p for p in (pattern, climb) if p) + ", flown from the pattern start"


# the evaluation sweeps' smoke runs (with tracking.quick_subset's one seed and intensity)
SWEEP_QUICK = QuickFlights(pattern_s=10.0, vertical_top_m=30.0, altitude_m=20.0)
# the PPO recipes' smoke runs: each regime's own flights only
PPO_QUICK = {"horizontal": QuickFlights(pattern_s=5.0, altitude_m=10.0),
             "vertical": QuickFlights(vertical_top_m=10.0, vertical_hold_s=1.0)}
