"""Shared fixtures: small, quiet configurations so physics tests isolate one effect at a time."""
from __future__ import annotations

from dataclasses import replace

import os

import pytest
import torch

from quadwind_trl.cache import CACHE_DIR_VARIABLE, cache_dir
from quadwind_trl.envs.compile_cache import COMPILE_CACHE_ENV
from quadwind_trl.config import ControllerConfig, EnvConfig, SensorConfig, TrajectoryConfig, TurbulenceConfig, WindProfileConfig

torch.set_num_threads(1)


# the user's compile cache, as it is before any test moves the cache root
USER_COMPILE_CACHE = os.environ.get(COMPILE_CACHE_ENV) or str(cache_dir() / "compile")


@pytest.fixture(autouse=True)
def own_cache(tmp_path_factory, monkeypatch):
    """Each test keeps what the library caches (PD's evaluation flights, ``rl.pd_flights``) in a
    folder of its own: no test reads what another test, or the user, flew. Compiled steps keep
    the user's compile cache: a compilation per test would cost minutes, and its entries are
    keyed by graph, processor and torch version, so sharing them cannot change what a test flies."""
    monkeypatch.setenv(CACHE_DIR_VARIABLE, str(tmp_path_factory.mktemp("cache")))
    monkeypatch.setenv(COMPILE_CACHE_ENV, USER_COMPILE_CACHE)


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


@pytest.fixture(scope="module")
def short_horizontal(tmp_path_factory):
    """3 horizontal cases (one per split under --quick) of 10 s patterns at 6-8 m: about 17 s flights,
    every one with windows past the crop (the --quick set's 25 s flights cost half as much again)."""
    from quadwind_trl.data import GenerationSpec
    from quadwind_trl.envs import RegimeRanges
    from quadwind_trl.regimes import DATASET_SEED
    from test_data import generated_once

    cfg = replace(EnvConfig(), trajectories=replace(TrajectoryConfig(), horizontal_duration_s=10.0))
    spec = GenerationSpec("horizontal", cases=3, seed=DATASET_SEED["horizontal"], config=cfg,
                          ranges=RegimeRanges(altitude_m=(6.0, 8.0)))
    return generated_once(tmp_path_factory, "flights_horizontal_short", spec, max_batch=16)
