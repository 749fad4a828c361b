"""The quickstart's first flight: the shipped wind-aware policy against PD on a few paper-scale
episodes, so that a newcomer's first run shows the result, which the toy pipeline beside it
cannot (``recipes/first_flight.py``; ``scripts/quickstart.sh`` runs it first).

The episodes are the shipped policy's own world: the vehicle, sensors and atmosphere of the env
config in its checkpoint, horizontal patterns at the RL regime's 100 m, one mean wind speed and
turbulence intensity; the other wind parameters (direction, shear, veer, length scale) are drawn
by Latin hypercube over the RL training ranges with :data:`~quadwind_trl.regimes.FIRST_FLIGHT_SEED`,
a seed nothing is chosen on. Only the pattern is shorter than in training (180 s), flown from
its start (:class:`~quadwind_trl.quick.QuickFlights`), so no second goes to the climb.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch
from tensordict import TensorDict
from torch import Tensor

from ..envs.runner import FlightResults
from ..envs.scenarios import RegimeRanges, sample_regimes
from ..envs.trajectories import HORIZONTAL, trajectory_ids
from ..estimator import EstimatorBundle
from ..quick import QuickFlights
from ..regimes import FIRST_FLIGHT_SEED, HORIZONTAL_RL
from .ablation import episode_table, fly_controllers, summarize_ablation

CONTROLLERS = ("pd", "aware")  # the baseline and the paper's system (estimator in the loop)
MAX_PATTERN_S = 180.0  # the shipped policy's patterns (TrajectoryConfig.horizontal_duration_s)


@dataclass(frozen=True)
class FirstFlight:
    """What the first flight flies: ``episodes`` patterns, cycling through the horizontal ones."""

    episodes: int = 16
    pattern_s: float = 30.0  # s of each pattern, from its start
    wind_m_s: float = 10.0  # mean wind U at the 10 m reference height
    intensity: float = 0.15  # turbulence intensity
    seed: int = FIRST_FLIGHT_SEED

    def __post_init__(self):
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes < 1:
            raise ValueError(f"FirstFlight.episodes={self.episodes!r}: expected an integer >= 1")
        if not 0.0 < self.pattern_s <= MAX_PATTERN_S:
            raise ValueError(f"FirstFlight.pattern_s={self.pattern_s!r}: expected 0 < pattern_s <= {MAX_PATTERN_S:g} s")
        _ = self.ranges  # building it checks the wind speed and intensity against the scenario ranges

    @property
    def ranges(self) -> RegimeRanges:
        """The RL training ranges, the wind speed and intensity pinned to this flight's."""
        return replace(HORIZONTAL_RL, wind_speed_m_s=(self.wind_m_s, self.wind_m_s), intensity=(self.intensity, self.intensity))

    @property
    def flights(self) -> QuickFlights:
        return QuickFlights(pattern_s=self.pattern_s)

    def scenarios(self) -> TensorDict:
        """The episodes: independent wind cases (own direction, turbulence and sensor seeds), the
        patterns in turn."""
        cases = sample_regimes(self.episodes, self.ranges, self.seed)
        cases["traj_id"] = trajectory_ids([HORIZONTAL[i % len(HORIZONTAL)] for i in range(self.episodes)])
        return self.flights.scenarios(cases, self.ranges.top_altitude_m)


def fly_first_flight(flight: FirstFlight, policy_path: str | Path, estimator: EstimatorBundle
                     ) -> tuple[TensorDict, dict[str, FlightResults]]:
    """The episodes and PD's and the policy's flights of them (with traces), in one batch each."""
    scenarios = flight.scenarios()
    # eager: at this size compiling the step costs more than it saves (one thread, the other core
    # busy: 16 x 30 s in 51 s eager, 132 s compiled; 8 x 60 s in 99 s eager, 124 s compiled)
    results = fly_controllers("horizontal", scenarios, policy_path, estimator, CONTROLLERS,
                              config_override=flight.flights.config, compile_step=False)
    return scenarios, results


def median_episode(baseline: Tensor, other: Tensor) -> int:
    """The row whose own RMSE reduction (``1 - other / baseline``) is the median (the lower one of
    an even count): the episode a figure shows, chosen by rule rather than by its looks."""
    reduction = 1.0 - other.double() / baseline.double()
    return int(torch.argsort(reduction, stable=True)[(reduction.numel() - 1) // 2])


def summarize_first_flight(flight: FirstFlight, scenarios: TensorDict, results: dict[str, FlightResults]) -> dict:
    """The ablation's summary of the two controllers (paired statistics per axis, per-episode
    table), the settings flown, each episode's wind direction and the episode shown."""
    summary = summarize_ablation("first_flight", episode_table(scenarios, results), CONTROLLERS)
    summary["first_flight"] = {**asdict(flight), "flights": flight.flights.describe()}
    summary["wind_dir_deg"] = scenarios["wind_dir_deg"].tolist()
    summary["shown_episode"] = median_episode(results["pd"].rmse_xy, results["aware"].rmse_xy)
    return summary
