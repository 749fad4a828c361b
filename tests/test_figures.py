"""The ablation's figures and the PPO learning curves, drawn from small made-up inputs of the shapes
the recipes pass (no flight: what is checked is what gets drawn, and where)."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from quadwind_trl.envs.runner import FlightResults
from quadwind_trl.envs.trajectories import trajectory_id
from quadwind_trl.evaluation import figures
from quadwind_trl.evaluation.ablation import episode_table_from_json, summarize_ablation

PNG = b"\x89PNG\r\n\x1a\n"
WINDS = (4.0, 8.0)
STEPS = 30  # 10 Hz samples of a flight record


def _sweep(sweep: str, trajectories: tuple[str, ...]) -> tuple[TensorDict, dict[str, FlightResults], dict]:
    """Every trajectory at every wind level, two intensities: the scenarios, each controller's
    flights (a 1 s climb to 20 m, then the pattern, PD furthest off it and wind-aware RL closest) and
    the ablation summary of their RMSEs."""
    rows = [(traj, wind, inten) for traj in trajectories for wind in WINDS for inten in (0.05, 0.25)]
    n = len(rows)
    wind = torch.tensor([w for _, w, _ in rows])
    scenarios = TensorDict({"traj_id": torch.tensor([trajectory_id(t) for t, _, _ in rows]), "wind_speed_ref_m_s": wind},
                           batch_size=[n])
    t = torch.arange(STEPS, dtype=torch.float32) / 10.0
    ref = torch.stack((5.0 * torch.cos(t), 5.0 * torch.sin(t), (20.0 * t).clamp(max=20.0)), -1).expand(n, STEPS, 3)
    mean_wind = torch.stack((wind, torch.zeros(n), torch.zeros(n)), -1)[:, None].expand(n, STEPS, 3)
    valid = torch.ones(n, STEPS, dtype=torch.bool)
    valid[0, -3:] = False  # an episode that ended early
    results, columns = {}, {}
    for k, name in enumerate(("aware", "blind", "pd")):
        offset = 0.1 * (k + 1) * (1.0 + wind / 4.0)
        pos = ref + torch.stack((offset, -offset, 0.5 * offset), -1)[:, None]
        log = TensorDict({"valid": valid, "ref_pos": ref.clone(), ("truth", "pos"): pos, ("truth", "mean_wind"): mean_wind.clone()},
                         batch_size=[n, STEPS])
        results[name] = FlightResults(index=torch.arange(n), rmse_xy=offset * 2**0.5, rmse_z=0.5 * offset,
                                      crashed=torch.zeros(n, dtype=torch.bool), log=log)
        columns |= {f"{name}_rmse_xy": results[name].rmse_xy.tolist(), f"{name}_rmse_z": results[name].rmse_z.tolist(),
                    f"{name}_rmse": results[name].rmse.tolist(), f"{name}_crashed": [False] * n}
    columns |= {"trajectory": [r[0] for r in rows], "wind_speed_ref_m_s": wind.tolist(),
                "turb_intensity": [r[2] for r in rows], "case_id": list(range(n))}
    summary = summarize_ablation(sweep, episode_table_from_json(columns), ["pd", "blind", "aware"])
    return scenarios, results, summary


@pytest.mark.parametrize("sweep, trajectories", [("horizontal", ("racetrack_h", "lawnmower_h")),
                                                 ("vertical", ("figure8_3d", "spiral_ascent"))])
def test_ablation_figures_draws_each_listed_panel_and_the_trace(sweep, trajectories, tmp_path):
    """A sweep's figures are its summary panels and the trace of its listed trajectory at the
    strongest wind, saved under the names ABLATION_FIGURES gives, in that order."""
    scenarios, results, summary = _sweep(sweep, trajectories)
    paths = figures.ablation_figures(sweep, scenarios, results, summary, tmp_path / "figures")
    panels, (_, traj, trace) = figures.ABLATION_FIGURES[sweep]
    assert traj in trajectories
    assert paths == [tmp_path / "figures" / name for _, name in panels] + [tmp_path / "figures" / trace]
    assert all(path.read_bytes().startswith(PNG) for path in paths)
    with pytest.raises(ValueError, match="sweep='other'"):
        figures.ablation_figures("other", scenarios, results, summary, tmp_path)


def test_the_trace_follows_the_middle_episode_of_the_trajectory_at_that_wind(tmp_path, monkeypatch):
    """The horizontal trace draws the pattern part of one flight (the climb dropped): PD's and the
    wind-aware policy's tracks and errors, against the reference, with their RMSEs."""
    scenarios, results, _ = _sweep("horizontal", ("racetrack_h", "lawnmower_h"))
    drawn = {}
    monkeypatch.setattr(figures, "save_figure", lambda fig, path: drawn.setdefault("fig", fig) and path)
    figures.trace_top_down(scenarios, results, "lawnmower_h", 8.0, tmp_path / "trace.png")
    track, error = drawn["fig"].axes
    row = 7  # lawnmower_h at 8 m/s: rows 6 and 7 (two intensities), the middle one is the second
    assert track.get_title() == "lawnmower_h, U = 8 m/s"
    labels = [t.get_text() for t in track.get_legend().get_texts()]
    assert labels == ["reference", f"PD baseline (xy RMSE {results['pd'].rmse_xy[row]:.2f} m)",
                      f"wind-aware RL (xy RMSE {results['aware'].rmse_xy[row]:.2f} m)"]
    climbed = int((results["pd"].log["ref_pos"][row, :, 2] >= 20.0 - 1e-3).sum())
    assert [len(line.get_xdata()) for line in error.get_lines()] == [climbed, climbed]
    np.testing.assert_allclose(error.get_lines()[0].get_ydata(), float(results["pd"].rmse_xy[row]), rtol=1e-5)
    figures.plt.close(drawn["fig"])


def _scalars(run, name: str, rows: list[tuple[int, float]]) -> None:
    path = run / "logs" / "ppo" / "scalars" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(f"{f},{v}\n" for f, v in rows))


def test_learning_curves_draw_a_row_per_regime_and_a_colour_per_kind(tmp_path, monkeypatch):
    """One row of three panels per regime; the seeds of one kind share a colour; a run without
    periodic evaluations draws none; a resumed run's repeated frames count once (the later row)."""
    runs = {name: tmp_path / name for name in ("ppo_horizontal_seed0", "ppo_horizontal_seed1",
                                               "ppo_horizontal_trained_blind_seed0", "ppo_vertical")}
    for k, run in enumerate(runs.values()):
        _scalars(run, "train/reward_mean.csv", [(256 * i, -1.0 + 0.1 * i + k) for i in range(1, 41)])
        _scalars(run, "train/action_scale.csv", [(256, 1.0), (512, 0.9), (512, 0.8)])
        if run.name != "ppo_vertical":
            _scalars(run, "eval/improvement_rmse_xy_pct.csv", [(1024, -5.0), (2048, 3.0)])
    drawn = {}
    monkeypatch.setattr(figures, "save_figure", lambda fig, path: drawn.setdefault("fig", fig) and path)
    assert figures.learning_curves(runs, tmp_path / "curves.png") == tmp_path / "curves.png"
    axes = drawn["fig"].axes
    assert len(axes) == 6 and [a.get_title() for a in axes[::3]] == ["horizontal: training reward", "vertical: training reward"]
    reward, evaluation, scale = axes[:3]
    assert [line.get_label() for line in reward.get_lines()] == ["horizontal_seed0", "horizontal_seed1", "horizontal_trained_blind_seed0"]
    colours = [line.get_color() for line in reward.get_lines()]
    assert colours[0] == colours[1] != colours[2]
    assert len(reward.get_lines()[0].get_xdata()) == 40 - 2 + 1  # a moving mean over 40 // 20 = 2 rows
    assert len(evaluation.get_lines()) == 3 + 1 and len(axes[4].get_lines()) == 1  # the zero line only
    assert list(scale.get_lines()[0].get_ydata()) == [1.0, 0.8]
    figures.plt.close(drawn["fig"])
