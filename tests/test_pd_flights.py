"""PD's side of the trainer's evaluation (``rl.pd_flights``): flown on the simulator alone, kept
between runs under a name that changes with everything its flights depend on, and an entry that
cannot be trusted flown again."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from quadwind_trl.regimes import classical_controller
from quadwind_trl.rl import pd_flights
from quadwind_trl.rl.envs import EnvFactory
from quadwind_trl.rl.paired import fly_paired
from quadwind_trl.cache import CACHE_DIR_VARIABLE, cache_dir
from quadwind_trl.rl.pd_flights import PD_EVAL_KEYS, flight_key, pd_env, pd_evaluation
from test_ppo import _two_hover_validation_episodes, hover_spec


def _eval_env(spec, seed: int = 1):
    return EnvFactory(spec)(num_envs=2, seed=seed, desync_steps=0)


@pytest.fixture
def flights(monkeypatch) -> list[int]:
    """Counts PD's flights: one entry per call of ``fly_paired`` from ``rl.pd_flights``."""
    flown: list[int] = []

    def counted(*args, **kwargs):
        flown.append(1)
        return fly_paired(*args, **kwargs)

    monkeypatch.setattr(pd_flights, "fly_paired", counted)
    return flown


def _same(a: dict, b: dict) -> bool:
    return all(torch.equal(a[k], b[k]) for k in PD_EVAL_KEYS)


def test_the_evaluation_flies_pd_on_the_simulator_alone_and_its_flights_do_not_change():
    """PD's evaluation flights skip the policy's input pipeline (the estimator's ticks, the
    observation, its normalisation): they are those flown through the whole stack to the bit. A
    base law that reads the wind estimate keeps the stack: its estimate changes what it flies."""
    sc = _two_hover_validation_episodes()
    env = _eval_env(hover_spec())
    assert pd_env(env) is env.base_env
    bare, full = (fly_paired({"pd": (e, None)}, sc)["pd"] for e in (pd_env(env), env))
    for key in ("rmse_xy", "rmse_z", "crashed", "nav_rmse_xy", "nav_rmse_z"):
        assert torch.equal(getattr(bare, key), getattr(full, key)), key
    assert float(full.rmse_xy.max()) > 0.0
    wind_reading = _eval_env(_feed_forward(hover_spec()))
    assert pd_env(wind_reading) is wind_reading


def _feed_forward(spec):
    law = classical_controller("horizontal", "pd_ff")[0]
    return replace(spec, config=replace(spec.config, controller=replace(spec.config.controller, **law)))


def test_pd_flights_are_kept_and_read_back_by_a_run_of_another_seed(flights):
    """The first evaluation flies PD and keeps its results; a later run's (here of another seed,
    which flights of given scenarios do not use) reads them without flying, and they are the
    flights that run would have flown, to the bit."""
    sc = _two_hover_validation_episodes()
    spec = hover_spec()
    first = pd_evaluation(_eval_env(spec), spec, sc)
    assert len(flights) == 1 and len(list((cache_dir() / "pd_flights").glob("*.pt"))) == 1
    other_seed = replace(spec, seed=5)
    env = _eval_env(other_seed, seed=6)
    again = pd_evaluation(env, other_seed, sc)
    assert len(flights) == 1 and _same(first, again)
    flown = fly_paired({"pd": (pd_env(env), None)}, sc)["pd"]
    assert _same(first, {k: getattr(flown, k) for k in PD_EVAL_KEYS})


@pytest.mark.parametrize("damage", ["bytes", "shape"])
def test_an_entry_that_cannot_be_trusted_is_flown_again_and_replaced(flights, damage):
    sc = _two_hover_validation_episodes()
    spec = hover_spec()
    env = _eval_env(spec)
    first = pd_evaluation(env, spec, sc)
    (path,) = (cache_dir() / "pd_flights").glob("*.pt")
    if damage == "bytes":
        path.write_bytes(path.read_bytes()[:40])  # a write cut short
    else:
        torch.save({k: v[:1] for k, v in first.items()}, path)  # another selection's results
    assert _same(pd_evaluation(env, spec, sc), first) and len(flights) == 2
    assert _same(torch.load(path, weights_only=True), first)  # replaced by the flights flown again


def test_the_name_changes_with_what_pd_flies_and_not_with_the_seed():
    sc = _two_hover_validation_episodes()
    spec = hover_spec()
    key = flight_key(spec, 2, sc)
    assert flight_key(replace(spec, seed=9), 2, sc) == key
    other_scenarios = sc.clone()
    other_scenarios["turb_seed"][1] += 1
    windier = replace(spec.config, wind=replace(spec.config.wind, max_horizontal_wind_m_s=3.0))
    others = [flight_key(replace(spec, config=windier), 2, sc), flight_key(replace(spec, compile_step=True), 2, sc),
              flight_key(spec, 3, sc), flight_key(spec, 2, other_scenarios)]
    assert len({key, *others}) == 5


def test_a_base_law_that_reads_the_wind_estimate_flies_every_time(flights):
    sc = _two_hover_validation_episodes()
    spec = _feed_forward(hover_spec())
    env = _eval_env(spec)
    first, second = pd_evaluation(env, spec, sc), pd_evaluation(env, spec, sc)
    assert len(flights) == 2 and _same(first, second)
    assert not (cache_dir() / "pd_flights").exists()


def test_a_cache_that_cannot_be_written_costs_only_the_next_flights(flights, monkeypatch, tmp_path):
    blocked = tmp_path / "a_file"
    blocked.write_text("not a folder")
    monkeypatch.setenv(CACHE_DIR_VARIABLE, str(blocked))
    sc = _two_hover_validation_episodes()
    spec = hover_spec()
    env = _eval_env(spec)
    first, second = pd_evaluation(env, spec, sc), pd_evaluation(env, spec, sc)
    assert len(flights) == 2 and _same(first, second)
