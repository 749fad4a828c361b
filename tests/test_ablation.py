"""The ablation's controllers: a policy trained with its wind inputs zeroed flies the same worlds as
the others, and its comparison with the wind-aware policy is summarised beside the paper's; the
classical controllers fly those worlds too."""
from __future__ import annotations

import copy
import json
from dataclasses import replace

import pytest
import torch

from quadwind_trl.estimator import load_estimator
from quadwind_trl.evaluation.ablation import episode_table, episode_table_from_json, fly_controllers, summarize_ablation
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.evaluation.statistics import paired_summary
from quadwind_trl.studies.paired_ablation import perception_tables
from quadwind_trl.quick import SWEEP_QUICK
from quadwind_trl.regimes import SWEEPS, classical_controller
from quadwind_trl.validation import load_checkpoint

AWARE = CHECKPOINT_DIR / "policy_horizontal.pt"


def _saved_as(tmp_path, name: str, change) -> str:
    """The shipped horizontal policy with ``change`` applied to a copy of its payload."""
    payload = copy.deepcopy(load_checkpoint(AWARE, "policy"))
    change(payload)
    path = tmp_path / name
    torch.save(payload, path)
    return str(path)


def _trained_blind(payload: dict) -> None:
    payload["env_spec"]["wind_input"] = "zero"


@pytest.fixture(scope="module")
def episodes():
    # three quick-sweep episodes on 3 s patterns: what is checked (the same worlds, to the bit; the
    # summary's arithmetic) does not depend on the flights' length, the test's cost does
    sweep = SWEEPS["horizontal"]
    scenarios, _ = sweep_setup(sweep, quick=True)
    return sweep, scenarios[:3], replace(SWEEP_QUICK, pattern_s=3.0).config


def test_trained_blind_flies_the_same_worlds(tmp_path, episodes):
    # the shipped policy relabelled as trained without wind inputs: flown with them zeroed, it must
    # reproduce the zeroed ("blind") flights to the bit, so both controllers flew the same worlds
    sweep, scenarios, override = episodes
    blind = _saved_as(tmp_path, "blind.pt", _trained_blind)
    results = fly_controllers("horizontal", scenarios, AWARE, load_estimator("horizontal"),
                              ("pd", "blind", "aware", "trained_blind"), config_override=override,
                              trained_policies={"trained_blind": blind},
                              compile_step=False)  # eager: compiling four envs cost 100 s of the test's 118
    for metric in ("rmse_xy", "rmse_z", "crashed"):
        assert torch.equal(getattr(results["trained_blind"], metric), getattr(results["blind"], metric))
    summary = summarize_ablation(sweep.name, episode_table(scenarios, results), list(results))
    # a results file's tables can be recomputed from its persisted episode table, to the bit
    persisted = json.loads(json.dumps(summary["episodes_table"]))
    assert summarize_ablation(sweep.name, episode_table_from_json(persisted), list(results)) == summary
    assert set(summary["rmse_z"]) >= {"aware", "trained_blind", "trained_perception", "decomposition"}
    block = summary["rmse_xy"]
    # perception between the two trained policies is scored like the paper's zeroing: aware vs blind
    assert block["trained_perception"]["improvement"] == pytest.approx(
        100.0 * (1.0 - block["distribution"]["aware"]["mean"] / block["distribution"]["trained_blind"]["mean"]))
    assert block["trained_perception"]["other_mean"] == block["distribution"]["aware"]["mean"]
    for row in block["by_wind"].values():
        assert row["trained_blind"] == pytest.approx(row["blind"])
        assert row["trained_perception"] == pytest.approx(100.0 * (row["blind"] - row["aware"]) / row["blind"])
    # the report's table has one row per wind level, each with both measures of perception
    rows = [line for line in perception_tables({"horizontal": block}) if line.startswith("| ") and "(m/s)" not in line]
    assert [row.split(" | ")[0][2:] for row in rows] == sorted(block["by_wind"], key=float)


def test_trained_blind_refuses_a_policy_that_saw_the_wind_or_flew_another_vehicle(tmp_path, episodes):
    _, scenarios, override = episodes
    estimator = load_estimator("horizontal")

    def fly(path):
        fly_controllers("horizontal", scenarios, AWARE, estimator, ("pd", "trained_blind"), config_override=override,
                        trained_policies={"trained_blind": path})

    with pytest.raises(ValueError, match=r"needs trained_policies\['trained_blind'\]"):
        fly(None)
    with pytest.raises(ValueError, match="wind_input='estimate'"):
        fly(AWARE)

    def heavier(payload):
        _trained_blind(payload)
        payload["env_spec"]["env_config"]["vehicle"]["mass_kg"] *= 1.1

    with pytest.raises(ValueError, match="another env config"):
        fly(_saved_as(tmp_path, "heavier.pt", heavier))


def test_seed_table_reports_every_seed_and_the_mean_range_and_t_interval():
    from quadwind_trl.studies.seeds import seeds_section

    def result(aware: float, blind: float) -> dict:
        block = {"aware": {"improvement": aware, "wins": 200, "n": 225}, "trained_blind": {"improvement": blind, "wins": 190, "n": 225},
                 "trained_perception": {"improvement": aware - blind}}
        return {"horizontal": {"rmse_xy": block}}

    text = seeds_section({"0": result(50.0, 30.0), "1": result(40.0, 35.0), "2": result(60.0, 20.0)})
    rows = {tuple(line.split(" | ")[:2]): line.split(" | ")[2:] for line in text.splitlines() if line.startswith("| ")}
    aware = rows["| horizontal xy", "wind-aware vs PD"]
    assert aware[:3] == ["+50.0 (200/225)", "+40.0 (200/225)", "+60.0 (200/225)"]
    assert aware[3] == "+50.0 (+40.0 to +60.0)"
    assert aware[4] == "+25.2 to +74.8 |"  # 50 +- t(0.975, 2) 10 / sqrt(3)
    assert rows["| horizontal xy", "trained blind vs PD"][3] == "+28.3 (+20.0 to +35.0)"
    assert rows["| horizontal xy", "perception: wind-aware vs trained blind"][3] == "+21.7 (+5.0 to +40.0)"
    assert not any(sweep != "| horizontal xy" for sweep, _ in rows if sweep != "| sweep")  # no made-up rows



def _ablation_recipe(tmp_path, *controllers: str):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    return subprocess.run([sys.executable, str(root / "recipes" / "ablation.py"), "--quick", "--sweeps", "ood", "--eager",
                           "--results", str(tmp_path / "results"), "--figures", str(tmp_path / "figures"),
                           "--controllers", *controllers], cwd=root, capture_output=True, text=True)  # fmt: skip


@pytest.mark.slow  # flies the quick OOD sweep twice in a subprocess (about 40 s of CPU)
def test_ablation_recipe_with_pd_and_aware_only_writes_its_results_and_names_the_figures_it_cannot_draw(tmp_path):
    """The figures decompose the gain (PD, the blind residual, the wind-aware one): a run of PD and
    the wind-aware policy alone still writes its results and says why it draws no figure."""
    run = _ablation_recipe(tmp_path, "pd", "aware")
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    result = json.loads((tmp_path / "results" / "ablation_ood.json").read_text())
    assert result["controllers"] == ["pd", "aware"] and "by_wind" not in result["rmse_xy"]
    assert result["rmse_xy"]["aware"]["n"] == result["episodes"]
    assert "figures: none (they need the controllers pd, blind, aware)" in run.stdout
    assert not (tmp_path / "figures").exists() or not any((tmp_path / "figures").iterdir())


def test_ablation_recipe_without_pd_is_refused_before_it_flies(tmp_path, monkeypatch, capsys):
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "recipes" / "ablation.py"
    spec = importlib.util.spec_from_file_location("ablation_recipe", path)
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    monkeypatch.setattr(sys, "argv", [str(path), "--quick", "--sweeps", "ood", "--results", str(tmp_path / "results"),
                                      "--controllers", "aware", "blind"])
    with pytest.raises(SystemExit) as refused:
        recipe.main()
    assert refused.value.code == 2 and "pd is required, every result is paired against it" in capsys.readouterr().err
    assert not (tmp_path / "results").exists()


def test_classical_rows_are_summarised_against_pd_and_the_policy(tmp_path, episodes):
    """The classical controllers fly the same worlds with no policy: the pid row is, to the bit, the
    "pd" row (the base law alone) of a policy trained on that base; each classical row is paired
    against PD and against the wind-aware policy, and the feed-forward on the estimate against its
    blind twin (the estimate's worth to a law that cannot learn)."""
    sweep, scenarios, override = episodes
    scenarios = scenarios[:2]  # two worlds (a spread for the paired statistics); six flights of them are the cost
    law, _ = classical_controller("horizontal", "pid")

    def on_pid_base(payload: dict) -> None:
        payload["env_spec"]["env_config"]["controller"].update({k: list(v) if isinstance(v, tuple) else v
                                                                for k, v in law.items()})

    estimator = load_estimator("horizontal")
    controllers = ("pd", "aware", "pid", "pd_ff", "pd_ff_blind")
    results = fly_controllers("horizontal", scenarios, AWARE, estimator, controllers, config_override=override,
                              compile_step=False)
    on_base = fly_controllers("horizontal", scenarios, _saved_as(tmp_path, "on_pid.pt", on_pid_base), estimator, ("pd",),
                              config_override=override, compile_step=False)
    for metric in ("rmse_xy", "rmse_z"):
        assert torch.equal(getattr(on_base["pd"], metric), getattr(results["pid"], metric))
    for name in ("pid", "pd_ff", "pd_ff_blind"):  # each law acts: none flies PD's episodes
        assert not torch.equal(results[name].rmse_xy, results["pd"].rmse_xy)
    summary = summarize_ablation(sweep.name, episode_table(scenarios, results), controllers)
    xy = summary["rmse_xy"]
    assert set(xy["aware_vs_classical"]) == {"pid", "pd_ff", "pd_ff_blind"}
    assert xy["aware_vs_classical"]["pid"] == paired_summary(results["pid"].rmse_xy, results["aware"].rmse_xy)
    assert xy["feedforward"]["pd_ff"]["estimate_value"] == paired_summary(results["pd_ff_blind"].rmse_xy,
                                                                          results["pd_ff"].rmse_xy)
    assert xy["pid"] == paired_summary(results["pd"].rmse_xy, results["pid"].rmse_xy)
