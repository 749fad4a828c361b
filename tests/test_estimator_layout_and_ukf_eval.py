"""The turbulence layout of a generated dataset (``generate_flights.py --turbulence-layout``)
and the model-based UKF through the estimator evaluation (``evaluate_estimator.py --checkpoint ukf``)."""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from quadwind_trl.config import TurbulenceConfig, config_differences, config_to_dict
from quadwind_trl.data import GenerationSpec, generate_dataset, load_dataset
from quadwind_trl.data.generate import quick_spec
from quadwind_trl.estimator.ukf import UKFConfig
from quadwind_trl.regimes import DATASET_SEED
from test_data import micro_spec

ROOT = Path(__file__).resolve().parent.parent


def recipe(name: str):
    path = ROOT / "recipes" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{name}_recipe_issue27", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


generate_flights = recipe("generate_flights")
evaluate_estimator = recipe("evaluate_estimator")


# --- generate_flights --turbulence-layout -------------------------------------------------------


@pytest.mark.parametrize("quick", [False, True], ids=["paper_size", "quick"])
def test_paper_grid_spec_differs_from_the_shipped_one_only_in_the_turbulence_layout(quick):
    seed = DATASET_SEED["horizontal"]
    full, full_changes = generate_flights.build_spec("horizontal", quick, None, seed)
    grid, grid_changes = generate_flights.build_spec("horizontal", quick, None, seed, "paper_grid")
    # the default is the spec the shipped datasets were made with, unchanged
    shipped = quick_spec("horizontal", seed=seed, cases=3)[0] if quick else GenerationSpec("horizontal", 1000, seed)
    assert full == shipped and config_to_dict(full.config) == config_to_dict(shipped.config)
    assert grid.config.turbulence.layout == "paper_grid" and full.config.turbulence.layout == "full"
    assert config_differences(grid.config, full.config) == ["turbulence"]
    assert replace(grid.config.turbulence, layout="full") == full.config.turbulence
    assert replace(grid, config=full.config) == full and grid_changes == full_changes
    # the manifest and the resume fingerprint both record config_to_dict(spec.config)
    assert config_to_dict(grid.config)["turbulence"]["layout"] == "paper_grid"
    suffix = "_quick" if quick else ""
    assert generate_flights.default_out("horizontal", quick, "full") == f"data/flights_horizontal{suffix}"
    assert generate_flights.default_out("horizontal", quick, "paper_grid") == f"data/flights_horizontal_paper_grid{suffix}"


class Interrupt(Exception):
    pass


def test_an_interrupted_paper_grid_run_resumes_only_as_one_and_its_manifest_names_the_layout(tmp_path):
    # a small cube bank (the paper's 64^3 x 10 takes about 35 s to build); the full layout ignores it
    turbulence = replace(micro_spec().config.turbulence, cube_points=8, cube_length_scales_m=(150.0,), cube_bank_size=1)
    full = replace(micro_spec(), config=replace(micro_spec().config, turbulence=turbulence))
    grid = replace(full, config=replace(full.config, turbulence=replace(turbulence, layout="paper_grid")))
    out = tmp_path / "cube"

    def stop(chunk: int) -> None:
        raise Interrupt

    with pytest.raises(Interrupt):
        generate_dataset(out, grid, max_batch=3, progress=False, after_chunk=stop)
    with pytest.raises(ValueError, match="another spec or batch"):
        generate_dataset(out, full, max_batch=3, progress=False, resume=True)
    generate_dataset(out, grid, max_batch=3, progress=False, resume=True)
    _, manifest = load_dataset(out)
    assert manifest["config"]["turbulence"]["layout"] == "paper_grid"


# --- evaluate_estimator --checkpoint ukf --------------------------------------------------------


def run_recipe(monkeypatch, *argv: str) -> None:
    monkeypatch.setattr(sys, "argv", ["recipes/evaluate_estimator.py", *argv])
    evaluate_estimator.main()


def test_the_ukf_is_evaluated_with_the_network_tables_and_its_outputs_default_beside_them(short_horizontal, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default outputs land under the working directory
    run_recipe(monkeypatch, "--regime", "horizontal", "--checkpoint", "ukf", "--data", str(short_horizontal), "--quick",
               "--threads", "1")
    out = tmp_path / "results" / "experiments" / "ukf"
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file() and ".lock" not in p.name)
    assert all(p.startswith("results/experiments/ukf/") for p in written), written  # never the network's shipped outputs
    results = json.loads((out / "estimation_horizontal.json").read_text())
    assert results["checkpoint"] == "ukf" and results["data"]["turbulence_layout"] == "full"
    assert results["estimator"]["model_based"] == "WindUKF"
    ukf = UKFConfig()  # the stated model error, from its one default
    assert results["estimator"]["config"]["drag_scale"] == ukf.drag_scale and results["estimator"]["config"]["mass_scale"] == ukf.mass_scale
    s = results["test"]["summary"]
    assert s["n_windows"] > 0 and math.isfinite(s["per_window_vector_rmse"]) and math.isfinite(s["per_flight_vector_rmse"])
    assert str(results["val_best_tau_s"]) in results["val_ema_sweep"] and results["figures"]
    assert all((out / "figures" / Path(f).name).exists() for f in results["figures"].values())
    md = (out / "estimation.md").read_text()
    assert "Model-based estimator `WindUKF` (`--checkpoint ukf`): no training" in md
    assert f"drag_scale {ukf.drag_scale:g}" in md and f"mass_scale {ukf.mass_scale:g}" in md
    assert "best epoch" not in md and "deployed)" not in md and "(validation-best)" in md and " (best)" in md
    assert "](figures/estimation_horizontal_" in md  # links relative to the markdown's own folder
    # the field comparison (recipes/estimator_field.py) reads the same JSON: one UKF row on `full`,
    # with the field's own floor beside it, and names the evaluation it did not find
    monkeypatch.setattr(sys, "argv", ["recipes/estimator_field.py", "--evaluation", str(out / "estimation_horizontal.json"),
                                      str(tmp_path / "no_such.json"), "--md", str(tmp_path / "field.md")])
    recipe("estimator_field").main()
    field = (tmp_path / "field.md").read_text()
    floor = results["test"]["turbulence_floor"]["turbulence_rmse_flight_mean"]
    row = next(line for line in field.splitlines() if line.startswith("| UKF (model-based, untrained) | `full` |"))
    assert f"| {s['per_window_vector_rmse']:.2f} |" in row and f"| {floor:.2f} | {s['per_flight_vector_rmse'] - floor:+.2f} |" in row
    assert "| paper (its field, emulated by `paper_grid`) | - | 1.05 |" in field
    assert f"Not yet evaluated: `{tmp_path / 'no_such.json'}`." in field


def test_output_defaults_keep_the_network_on_its_shipped_paths():
    def paths(checkpoint, **given):
        args = argparse.Namespace(regime="horizontal", checkpoint=checkpoint, json=None, md=None, fig_dir=None, link_base=None)
        return [p.as_posix() for p in evaluate_estimator.output_paths(argparse.Namespace(**{**vars(args), **given}),
                                                                      checkpoint == "ukf")]

    assert paths(None) == ["results/estimation_horizontal.json", "docs/results/2_estimation.md", "docs/figures", "docs"]
    assert paths("ukf") == ["results/experiments/ukf/estimation_horizontal.json", "results/experiments/ukf/estimation.md",
                            "results/experiments/ukf/figures", "results/experiments/ukf"]
    assert paths("ukf", md="x.md", link_base="y")[1:4:2] == ["x.md", "y"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--regime", "horizontal", "--update-checkpoint"],
         "--update-checkpoint with --checkpoint ukf: a model-based estimator has no checkpoint"),
        (["--regime", "vertical"], "--checkpoint ukf with --regime vertical: the UKF reads the 'horizontal' features only"),
    ],
    ids=["update_checkpoint", "vertical"],
)
def test_what_the_ukf_cannot_do_is_refused_before_anything_loads(argv, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as refused:
        run_recipe(monkeypatch, *argv, "--checkpoint", "ukf", "--data", str(tmp_path / "no_such_dataset"))
    assert refused.value.code == 2 and message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no output folder made, no dataset read


def test_a_network_is_labelled_by_the_field_it_trained_on_and_a_bad_manifest_is_refused_by_name(tmp_path, monkeypatch, capsys):
    field_recipe = recipe("estimator_field")
    manifest = tmp_path / "net.json"
    for dataset, layout in (({"turbulence_layout": "paper_grid"}, "paper_grid"), ({}, TurbulenceConfig().layout)):
        manifest.write_text(json.dumps({"dataset": dataset}))  # {}: trained before the layout was recorded
        assert field_recipe.estimator_label({"checkpoint": str(tmp_path / "net.pt")}) == f"network trained on `{layout}`"
    evaluation = tmp_path / "eval.json"
    evaluation.write_text(json.dumps({"regime": "horizontal", "checkpoint": str(tmp_path / "missing.pt")}))
    monkeypatch.setattr(sys, "argv", ["recipes/estimator_field.py", "--evaluation", str(evaluation), "--md", str(tmp_path / "x.md")])
    with pytest.raises(SystemExit):
        field_recipe.main()
    assert f"--evaluation {evaluation}: cannot label its estimator (FileNotFoundError" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"paper_field='cube'; allowed: 'full', 'paper_grid'"):
        from quadwind_trl.evaluation.estimation_tables import field_comparison_markdown
        field_comparison_markdown([], "cube")
