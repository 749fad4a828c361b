"""The airspeed a flight demands of the vehicle, to hold against the flight envelope of
:mod:`quadwind_trl.envs.envelope` (an episode's or a sweep cell's; the study of every evaluated
regime against the envelope is :mod:`quadwind_trl.studies.envelope`).

Demand (airspeed, m/s) = the pattern's speed (flown straight into the wind on an upwind leg) + the
mean wind at the flight altitude (the atmosphere's own capped profile) + ``GUST_SIGMAS`` times the
longitudinal gust standard deviation ``sigma_u`` there (the atmosphere's own). The *sustained*
demand leaves the gusts out: what a whole upwind leg asks for. Turns and climbs are not counted.
"""
from __future__ import annotations

from dataclasses import replace

import torch
from tensordict import TensorDict

from ..config import EnvConfig
from ..envs.atmosphere import Atmosphere
from ._moved import moved

# a Gaussian gust exceeds 2 sigma_u 2.3 % of the time: a level the upwind legs of a 3-minute pattern meet
GUST_SIGMAS = 2.0


def pattern_speed(cfg: EnvConfig, regime: str) -> float:
    """The horizontal speed (m/s) a regime's patterns fly at."""
    return cfg.trajectories.vertical_speed_m_s if regime == "vertical" else cfg.trajectories.cruise_speed_m_s


def wind_at_altitude(scenarios: TensorDict, cfg: EnvConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean wind speed and ``sigma_u`` (m/s, ``[N]``) at each scenario's ``altitude_m`` (a vertical
    design's is its top, the climb's strongest wind), from the atmosphere's own profile and intensity."""
    # the profile and intensity only: no field is sampled, so one mode and no cube bank
    atmosphere = Atmosphere(cfg.wind, replace(cfg.turbulence, layout="full", num_modes=1))
    params, _ = atmosphere.init(scenarios)
    z = scenarios["altitude_m"].to(torch.float32)
    mean = atmosphere.mean_wind(params, z)
    return mean[..., :2].norm(dim=-1), atmosphere.turbulence_sigma(params, mean, z)[..., 0]


def airspeed_demand(scenarios: TensorDict, cfg: EnvConfig, speed_m_s: float) -> dict[str, torch.Tensor]:
    """Mean wind, ``sigma_u``, sustained and gust demand (m/s) of each scenario."""
    mean, sigma = wind_at_altitude(scenarios, cfg)
    sustained = speed_m_s + mean
    return {"mean_wind": mean, "sigma_u": sigma, "sustained": sustained, "demand": sustained + GUST_SIGMAS * sigma}


# the envelope study (every sweep and design against the envelope, the hold check, its tables
# and figure) moved to quadwind_trl.studies.envelope: the old names warn, for one release
__getattr__ = moved(__name__, {name: "quadwind_trl.studies.envelope" for name in (
    "DESIGN_SAMPLES", "DESIGN_SAMPLE_SEED", "shear_points", "sweep_cells", "design_row", "edge_wind_speed", "edge_table",
    "steady_wind_config", "hold_check", "first_not_held", "envelope_figure", "sweep_table", "design_table")})
