"""The PPO training runs on the results page: each run's command, budget, wall time and periodic
evaluations against PD, from its manifest (``recipes/ppo_horizontal.py``,
``recipes/ppo_vertical_curriculum.py``; ``results/policies/<run>.json``, or the run's own
``runs/<run>/policy.json``)."""
from __future__ import annotations

import json
from pathlib import Path

from .section import ReportContext, Section
from .tables import wall_time


def policy_runs(runs_dir: Path, kept_dir: Path) -> tuple[dict[str, dict], dict[str, Path]]:
    """Every PPO run by name (``ppo_horizontal_seed0``, ...): its manifest, the run's own
    ``RUNS/<name>/policy.json`` else the kept copy ``KEPT/<name>.json`` (``results/policies/``, in
    the repository), and the run directories whose logs can draw learning curves (``runs/`` is
    local: a fresh clone has the manifests but no curves)."""
    paths = {path.parent.name: path for path in sorted(runs_dir.glob("ppo_*/policy.json"))}
    for path in sorted(kept_dir.glob("ppo_*.json")):
        paths.setdefault(path.stem, path)
    manifests = {name: json.loads(paths[name].read_text()) for name in sorted(paths)}
    logged = {name: runs_dir / name for name in manifests if (runs_dir / name / "logs").exists()}
    return manifests, logged


def on_paper_pd(manifest: dict) -> bool:
    """Whether a policy's manifest trained its residual on the paper's PD (no classical addition;
    manifests older than the additions have none)."""
    controller = manifest.get("env_spec", {}).get("env_config", {}).get("controller", {})
    return controller.get("disturbance", "none") == "none" and not any(controller.get("ki_pos", ()))


def _base_note(manifest: dict) -> str:
    """For a policy trained on a classical base, what its "vs PD" figures are measured against."""
    if on_paper_pd(manifest):
        return ""
    controller = manifest["env_spec"]["env_config"]["controller"]
    parts = ["integral"] if any(controller.get("ki_pos", ())) else []
    parts += [{"observer": "disturbance observer", "l1": "L1 adaptive", "wind_model": "wind feed-forward"}[controller["disturbance"]]] if (
        controller.get("disturbance", "none") != "none") else []
    return f" (against its base, PD + {' + '.join(parts)})"


def training_section(manifests: dict[str, dict]) -> str:
    """Every PPO training run (from its JSON manifest): command, budget, wall time and the
    periodic deterministic evaluations against PD."""
    lines = ["## PPO training runs", "",
             "Each run's periodic evaluation flies a fixed set of held-out sweep episodes deterministically, paired with PD",
             "(`improvement` = 1 - mean RL xy RMSE / mean PD xy RMSE). Frames are policy decisions at 10 Hz (docs/rl.md).",
             "The runs' manifests are `results/policies/<run>.json`, beside the kept policy.", "",
             "| run | command | commit | decisions | wall time | evaluations: frames -> xy RMSE reduction vs PD (win rate) |",
             "|---|---|---|---|---|---|"]
    for name, m in manifests.items():
        evals = "; ".join(f"{int(e['frames']):,} -> {e['improvement_rmse_xy_pct']:+.1f} % ({e['win_rate']:.2f})"
                          for e in m.get("evals", []))
        command = "python recipes/" + m["command"].split("recipes/", 1)[-1]
        lines.append(f"| {name}{_base_note(m)} | `{command}` | `{m.get('git_commit')}` | {m['frames']:,} | "
                     f"{wall_time(m['wall_time_s'])} | {evals} |")
    lines += ["", "![learning curves](figures/learning_curves.png)", ""]
    return "\n".join(lines)


def _render(ctx: ReportContext) -> str | None:
    return training_section(dict(ctx.manifests)) if ctx.manifests else None


SECTION = Section("training", "PPO training runs", ("results/policies/ppo_*.json",), _render)
