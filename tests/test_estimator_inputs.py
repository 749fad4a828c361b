"""The estimator's inputs and network as experiment settings (window length,
trailing means, width and depth, a share of the training cases), and every consumer of a
checkpoint (the evaluation recipe, the env's ``WindEstimate``) reading its inputs from it."""
from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest
import torch

from quadwind_trl.estimator import EstimatorBundle
from quadwind_trl.estimator.training import estimator_inputs, load_estimator_data, quick_config, train_estimator
from quadwind_trl.rl.envs import make_env

ROOT = Path(__file__).resolve().parent.parent
SETTINGS = {"window": 20, "trailing_windows": (10, 30, 60)}


def test_a_network_with_other_inputs_trains_evaluates_and_flies(short_horizontal, tmp_path, monkeypatch):
    ed = load_estimator_data(short_horizontal, "horizontal", quick=True, progress=False, **SETTINGS)
    assert ed.windows.window == 20 and ed.info["trailing_windows"] == [10, 30, 60]
    assert ed.windows.channels[-1] == "avg60_u_T" and len(ed.windows.channels) == 26 + 3 * 11
    assert (short_horizontal / "features_horizontal_avg10-30-60.memmap").exists()  # beside, not over, the default cache
    cfg = quick_config("horizontal", epochs=1, windows_per_epoch=64, hidden=16, gru_layers=2, head_hidden=(16, 8), **SETTINGS)
    with pytest.raises(ValueError, match=r"prepared with \{'window': 20.*asks for \{'window': 60"):
        train_estimator(ed, quick_config("horizontal", epochs=1), tmp_path / "x.pt", log_dir=tmp_path / "logs", progress=False)
    out = tmp_path / "est.pt"
    train_estimator(ed, cfg, out, log_dir=tmp_path / "logs", progress=False)
    bundle = EstimatorBundle.load(out)
    assert bundle.model.gru.num_layers == 2 and bundle.model.gru.hidden_size == 16 and bundle.window == 20
    assert estimator_inputs(bundle) == SETTINGS
    # the evaluation recipe reads the checkpoint's inputs before it loads the data
    spec = importlib.util.spec_from_file_location("evaluate_estimator_inputs", ROOT / "recipes" / "evaluate_estimator.py")
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    monkeypatch.setattr(sys, "argv", ["evaluate_estimator.py", "--regime", "horizontal", "--checkpoint", str(out), "--data",
                                      str(short_horizontal), "--quick", "--threads", "1", "--taus", "0", "3",
                                      "--json", str(tmp_path / "e.json"), "--md", str(tmp_path / "e.md"),
                                      "--fig-dir", str(tmp_path / "fig"), "--link-base", str(tmp_path)])  # fmt: skip
    recipe.main()
    results = json.loads((tmp_path / "e.json").read_text())
    assert results["data"]["window"] == 20 and results["data"]["trailing_windows"] == [10, 30, 60]
    assert results["test"]["summary"]["n_windows"] > 0
    # the env's transform builds the extractor of those channels, and its ring holds 20 samples
    env = make_env("horizontal", bundle, 2, compile_step=False)
    td = env.rollout(3)
    assert td["next", "wind_hat"].shape == (2, 3, 2)
    west = next(t for t in env.transform if hasattr(t, "ring") and t.ring is not None)
    assert west.ring.windows(torch.arange(2)).shape == (2, 20, 59)



def test_the_experiments_table_names_what_each_run_changed():
    from quadwind_trl.estimator.training import TrainConfig
    from quadwind_trl.studies.estimation_experiments import config_change, experiments_markdown

    shipped = TrainConfig().to_dict()
    # a reference from before the input settings existed: their defaults are its values
    old = {k: v for k, v in shipped.items() if k not in ("window", "trailing_windows", "hidden", "gru_layers")}
    run = TrainConfig(trailing_windows=(100, 300, 1200), seed=1, compile=True).to_dict()
    run["loss"]["direction_weight"] = 0.0
    assert config_change(run, old) == "seed 0 -> 1; loss.direction_weight 0.05 -> 0.0; trailing_windows 100-300 -> 100-300-1200"
    assert config_change(TrainConfig().to_dict(), old) == "none (the shipped recipe)"
    val = {"per_window_vector_rmse": 1.5, "per_flight_vector_rmse": 0.8, "direction_mae_deg": 4.0, "vector_skill": 0.9}
    ref = {"config": old, "val_metrics": val, "best_epoch": 24, "epochs_run": 25, "parameters": 10}
    better = {**ref, "config": run, "val_metrics": {**val, "per_window_vector_rmse": 1.25}, "command": "python x", "git_commit": "abc"}
    md = experiments_markdown(ref, [("results/experiments/estimator/t.pt", better)], [])
    row = next(line for line in md.splitlines() if line.startswith("| `results/experiments/estimator/t.pt`"))
    assert "| 1.250 | -0.250 | 0.800 |" in row and "trailing_windows 100-300 -> 100-300-1200" in row
    assert "- `results/experiments/estimator/t.pt`: `python x` (commit `abc`)" in md
