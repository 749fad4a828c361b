"""The trajectory registry: built-in ids are stable, a pattern registered in user code is tabulated
as its closed form and flies, and persisted ids map back to names."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from torch import Tensor

from conftest import quiet_config
from quadwind_trl.envs import LevelPattern, QuadWindEnv, make_scenarios, register_trajectory, trajectory_ids
from quadwind_trl.envs.runner import fly
from quadwind_trl.envs.simulator import trajectory_library
from quadwind_trl.envs.trajectories import HORIZONTAL, HOVER, VERTICAL, ClimbingPattern, Pattern, base
from quadwind_trl.envs.trajectories import fixed_altitude_mask, ramp_integral, trajectory_name, trajectory_names
from quadwind_trl.evaluation.figures import _table


class RoundedSquare(LevelPattern):
    """A square of 40 m straights joined by 25 m radius corners, counter-clockwise, by arc length."""

    side_m = 40.0
    corner_radius_m = 25.0  # 4 m/s^2 of centripetal demand at the 10 m/s cruise

    def path(self, s: Tensor) -> Tensor:
        side, r = self.side_m, self.corner_radius_m
        leg = side + math.pi * r / 2  # one straight and one quarter turn
        u = torch.remainder(s, 4 * leg)
        k = torch.floor(u / leg)  # which side, counter-clockwise from the southern one
        v = u - k * leg
        a = (v - side).clamp_min(0.0) / r  # angle turned in the corner
        x = torch.where(v < side, v - side / 2, side / 2 + r * torch.sin(a))
        y = torch.where(v < side, v * 0 - side / 2 - r, -side / 2 - r * torch.cos(a))
        c, s_ = torch.cos(k * math.pi / 2), torch.sin(k * math.pi / 2)
        return torch.stack((c * x - s_ * y, s_ * x + c * y))


@pytest.fixture
def registry(monkeypatch):
    """A private copy of the registry: what a test registers is gone after it."""
    monkeypatch.setattr(base, "_REGISTRY", dict(base._REGISTRY))


def test_builtin_ids_keep_their_meaning():
    # datasets and results made before the registry store these ids
    assert trajectory_names() == HORIZONTAL + VERTICAL + (HOVER,)
    assert trajectory_ids(["loiter_circle_h", "lawnmower_h", "figure8_3d", "hover"]).tolist() == [0, 4, 7, 9]
    assert fixed_altitude_mask().tolist() == [True] * 5 + [False] * 4 + [True]
    assert trajectory_name(7) == "figure8_3d"
    with pytest.raises(ValueError, match="traj_id=10 is not registered; allowed: 0-9"):
        trajectory_name(10)


def test_registration_is_checked(registry):
    class NoPath(LevelPattern):
        pass

    class NoRate(ClimbingPattern):
        def path(self, s):
            return torch.stack((s, s))

    for cls in (NoPath, NoRate, int):
        with pytest.raises(TypeError, match="not a concrete subclass of Pattern"):
            register_trajectory("bad", cls)
    with pytest.raises(ValueError, match="'hover' is taken by Hover"):
        register_trajectory("hover", RoundedSquare)
    with pytest.raises(ValueError, match="non-empty string"):
        register_trajectory("", RoundedSquare)
    assert register_trajectory("rounded_square")(RoundedSquare) is RoundedSquare
    register_trajectory("rounded_square", RoundedSquare)  # the same class again: a no-op
    assert trajectory_names()[-1] == "rounded_square" and len(trajectory_names()) == 11
    assert issubclass(base.registered_patterns()["rounded_square"], Pattern)
    with pytest.raises(ValueError, match="rounded_squar' is not a registered trajectory; registered: .*rounded_square"):
        make_scenarios(1, traj_id="rounded_squar")


def test_user_pattern_reference_is_its_closed_form_and_flies(registry):
    register_trajectory("rounded_square", RoundedSquare)
    cfg = quiet_config()
    cfg = replace(cfg, trajectories=replace(cfg.trajectories, horizontal_duration_s=10.0))  # into the first corner
    lib = trajectory_library(cfg, torch.device("cpu"))
    assert lib.names[-1] == "rounded_square"  # a newly registered pattern gets new tables
    tc = cfg.trajectories
    n, altitude = 2, 12.0
    traj = trajectory_ids(["rounded_square"] * n)
    start, end = lib.schedule(traj, torch.full((n,), altitude))
    assert int(end[0] - start[0]) == round(tc.horizontal_duration_s / lib.dt)
    steps = torch.arange(int(start[0]), int(end[0]))
    ref = lib.reference(traj[:1].expand(len(steps)), steps, start[:1].expand(len(steps)), torch.full((len(steps),), altitude))
    # the closed form: P(s(t)) with s the smooth ramp to cruise speed (arc length: ds/dt = speed)
    t = (steps - start[0]).to(torch.float64) * lib.dt
    s = tc.cruise_speed_m_s * ramp_integral(t, tc.speed_ramp_s)
    expected = torch.stack([RoundedSquare(tc).path(si) for si in s])
    torch.testing.assert_close(ref.pos[:, :2].double(), expected, atol=2e-4, rtol=0)
    torch.testing.assert_close(ref.pos[:, 2], torch.full((len(steps),), altitude), atol=1e-5, rtol=0)
    cruise = t > tc.speed_ramp_s
    torch.testing.assert_close(ref.vel[cruise, :2].norm(dim=-1), torch.full((int(cruise.sum()),), tc.cruise_speed_m_s),
                               atol=1e-4, rtol=0)

    scenarios = make_scenarios(n, traj_id="rounded_square", altitude_m=altitude, start_step=-1,
                               turb_seed=[1, 2], sensor_seed=[3, 4])
    res = fly(QuadWindEnv(cfg, batch_size=[n]), scenarios)
    assert not res.crashed.any()
    assert (res.rmse_xy < 0.5).all(), res.rmse_xy  # still air: the PD's drag lag and its corners


def test_persisted_ids_read_back_as_names():
    old = {"episodes_table": {"traj_id": [0, 4, 9], "pd_rmse": [1.0, 2.0, 3.0]}}  # before names were stored
    new = {"episodes_table": {"trajectory": ["loiter_circle_h", "lawnmower_h", "hover"], "pd_rmse": [1.0, 2.0, 3.0]}}
    for summary in (old, new):
        assert _table(summary)["trajectory"].tolist() == ["loiter_circle_h", "lawnmower_h", "hover"]


def test_dataset_ids_are_checked_against_the_registry(tmp_path):
    from quadwind_trl.data.generate import _check_trajectory_ids

    _check_trajectory_ids(tmp_path, {"racetrack_h": 1, "figure8_3d": 7})
    with pytest.raises(ValueError, match=r"trajectory ids \{'rounded_square': 10\}.*register the dataset's patterns"):
        _check_trajectory_ids(tmp_path, {"racetrack_h": 1, "rounded_square": 10})


def test_a_pattern_is_tabulated_when_an_episode_first_flies_it():
    """The library differentiates a pattern only when ``schedule`` first meets its id: the other
    rows stay NaN (a read of one would show), and the filled row is the pattern's own table,
    padded with its last sample to the library's length."""
    from quadwind_trl.envs.trajectories.library import TrajectoryLibrary, _tabulate

    cfg = replace(quiet_config().trajectories, horizontal_duration_s=5.0)
    lib = TrajectoryLibrary(cfg, 0.01)
    assert torch.isnan(lib.table).all()
    row = lib.names.index("figure8_h")
    lib.schedule(trajectory_ids(["figure8_h", "figure8_h"]), torch.full((2,), 20.0))
    tabulated = ~torch.isnan(lib.table).any(-1).any(-1)
    assert tabulated.tolist() == [i == row for i in range(len(lib.names))]
    expected = _tabulate(base.registered_patterns()["figure8_h"](cfg), cfg, 0.01).to(torch.float32)
    steps = int(lib.pattern_steps[row])
    assert steps == expected.shape[0] < lib.table.shape[1]
    assert torch.equal(lib.table[row, :steps], expected)
    assert torch.equal(lib.table[row, steps:], expected[-1:].expand(lib.table.shape[1] - steps, -1))
