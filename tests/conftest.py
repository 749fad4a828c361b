"""Shared fixtures: small, quiet configurations so physics tests isolate one effect at a time."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from quadwind_trl.config import ControllerConfig, EnvConfig, SensorConfig, TrajectoryConfig, TurbulenceConfig, WindProfileConfig

torch.set_num_threads(1)


def quiet_config(**overrides) -> EnvConfig:
    """Truth feedback, no turbulence, no sensor noise: deterministic physics only."""
    cfg = EnvConfig(
        sensors=SensorConfig(enabled=False),
        turbulence=TurbulenceConfig(enabled=False),
        controller=ControllerConfig(feedback="truth"),
    )
    return replace(cfg, **overrides)


def short_trajectories() -> TrajectoryConfig:
    """The same patterns, flown briefly (tests must be quick)."""
    return TrajectoryConfig(horizontal_duration_s=30.0, vertical_top_m=45.0, hover_duration_s=20.0)


@pytest.fixture
def quiet() -> EnvConfig:
    return quiet_config()


def windy_config(cap_m_s: float = 20.0) -> EnvConfig:
    return quiet_config(wind=WindProfileConfig(max_horizontal_wind_m_s=cap_m_s))
