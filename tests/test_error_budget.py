"""The error budget's idealisations change exactly what they name."""
from dataclasses import fields

import pytest
import torch

from quadwind_trl.config import EnvConfig, SensorChannelConfig, with_sensing
from quadwind_trl.studies.error_budget import with_wind
from quadwind_trl.regimes import VERTICAL_SWEEP


def _channels(cfg: EnvConfig) -> dict[str, SensorChannelConfig]:
    return {f.name: getattr(cfg.sensors, f.name) for f in fields(cfg.sensors)
            if isinstance(getattr(cfg.sensors, f.name), SensorChannelConfig)}


def test_navigation_is_the_shipped_vehicle():
    cfg = EnvConfig()
    assert with_sensing(cfg, "navigation") == cfg


def test_no_bias_zeroes_every_bias_and_keeps_the_noise():
    cfg = EnvConfig()
    out = with_sensing(cfg, "no_bias")
    before, after = _channels(cfg), _channels(out)
    assert set(before) == set(after) and len(after) == 7
    for name, ch in after.items():
        assert ch.bias_drive_std_per_sqrt_s == 0.0 and ch.bias_std == 0.0
        assert ch.noise_std == before[name].noise_std and ch.rate_hz == before[name].rate_hz
    assert out.controller == cfg.controller and out.sensors.enabled


def test_true_state_changes_only_the_pd_feedback():
    cfg = EnvConfig()
    out = with_sensing(cfg, "true_state")
    assert out.controller.feedback == "truth" and cfg.controller.feedback != "truth"
    assert out.sensors == cfg.sensors and out.navigation == cfg.navigation


def test_with_wind_keeps_every_other_field():
    scenarios = VERTICAL_SWEEP.scenarios()[:12]
    mean_only, still = with_wind(scenarios, "mean_only"), with_wind(scenarios, "still")
    assert (mean_only["turb_intensity"] == 0).all() and (still["wind_speed_ref_m_s"] == 0).all()
    assert torch.equal(mean_only["wind_speed_ref_m_s"], scenarios["wind_speed_ref_m_s"])
    assert (scenarios["turb_intensity"] > 0).all() and (scenarios["wind_speed_ref_m_s"] > 0).all()  # input untouched
    for key in ("turb_seed", "sensor_seed", "traj_id", "wind_dir_deg"):
        assert torch.equal(still[key], scenarios[key])
    assert with_wind(scenarios, "full") is not scenarios


def test_unknown_modes_are_refused():
    with pytest.raises(ValueError):
        with_sensing(EnvConfig(), "perfect")
    with pytest.raises(ValueError):
        with_wind(VERTICAL_SWEEP.scenarios()[:1], "calm")
