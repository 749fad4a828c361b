"""Evaluate a trained wind estimator: the paper's estimation tables and figures.

    python recipes/evaluate_estimator.py --regime horizontal --data data/flights_horizontal \
        [--checkpoint quadwind_trl/checkpoints/estimator_horizontal.pt] [--unseen-data DIR]
    python recipes/evaluate_estimator.py --regime vertical --data data/flights_vertical \
        --unseen-data data/flights_vertical_unseen --update-checkpoint
    python recipes/evaluate_estimator.py --regime horizontal --data data/flights_horizontal --checkpoint ukf

On the held-out test wind cases of --data (the training split, by wind case) and, with
--unseen-data, on every flight of an independently generated LHS design (a disjoint --seed):

* estimates at every 10 Hz sample past each flight's crop (--stride 1);
* metrics (summary; by true wind speed, altitude band, trajectory); vertical: skill scores and the
  altitude-speed slope;
* the EMA post-filter sweep over tau on the validation flights (``ema_scan`` over each flight's
  sequence of estimates), then raw vs filtered on test (and unseen);
* markdown tables beside the paper's numbers in --md (this regime's section is replaced, the other
  regime's kept), figures in --fig-dir, all numbers in --json.

The tables, figures and the evaluation itself are library code (``quadwind_trl.evaluation``:
``estimation_run``, ``estimation_tables``, ``estimation_figures``); this script parses the
arguments, loads, calls them and writes the outputs. The validation-best tau is the deployed
one: --update-checkpoint records it, with the evaluation metrics, in the checkpoint's manifest,
and the PPO recipes train with it (``quadwind_trl.rl.envs.validated_tau_s``); the paper's tau
(``quadwind_trl.estimator.ema.DEFAULT_TAU_S``, 3 s) is reported beside it. Policies record the
tau they trained with, so re-evaluating an estimator never changes how a trained policy flies.

``--checkpoint ukf`` evaluates the model-based ``WindUKF`` instead (horizontal only): no
checkpoint and no training, so no training-set check and no --update-checkpoint; it is built on
the --data dataset's own airframe, against which its stated model error applies. Its outputs
default to results/experiments/ukf/, never over the network's shipped tables and figures.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

import torch

from quadwind_trl.config import EnvConfig, config_from_dict
from quadwind_trl.estimator import DEFAULT_TAU_S, EstimatorBundle, WindEstimator
from quadwind_trl.estimator.checkpoint import MODEL_BASED_ESTIMATORS, load_estimator
from quadwind_trl.estimator.training import estimator_inputs, load_estimator_data
from quadwind_trl.estimator.ukf import WindUKF
from quadwind_trl.evaluation.estimation import TAU_SWEEP_S
from quadwind_trl.evaluation.estimation_figures import estimation_figures
from quadwind_trl.evaluation.estimation_run import run_estimation
from quadwind_trl.evaluation.estimation_tables import estimation_markdown, replace_section
from quadwind_trl.manifest import CHECKPOINT_DIR, command_line, git_commit, platform_info, repo_relative
from quadwind_trl.outputs import hold_for_command

#: a model-based estimator's outputs go under here by default, never over the network's shipped ones
MODEL_BASED_RESULTS = Path("results") / "experiments"


def output_paths(args: argparse.Namespace, model_based: bool) -> tuple[Path, Path, Path, Path]:
    """``--json``, ``--md``, ``--fig-dir`` and ``--link-base``, the unset ones defaulted: the network's
    shipped outputs, or for a model-based estimator ``results/experiments/<name>/`` (figure links
    then relative to that folder, where its markdown stands alone)."""
    if model_based:
        root = MODEL_BASED_RESULTS / args.checkpoint
        defaults = (root / f"estimation_{args.regime}.json", root / "estimation.md", root / "figures", root)
    else:
        defaults = (Path("results") / f"estimation_{args.regime}.json", Path("docs/results/2_estimation.md"),
                    Path("docs/figures"), Path("docs"))  # fmt: skip
    given = (args.json, args.md, args.fig_dir, args.link_base)
    return tuple(Path(g) if g is not None else d for g, d in zip(given, defaults))


def refuse_model_based_misuse(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Exit with a message for what a model-based estimator cannot do, before anything loads."""
    name = args.checkpoint
    if args.update_checkpoint:
        p.error(f"--update-checkpoint with --checkpoint {name}: a model-based estimator has no checkpoint to record "
                "the evaluation in (allowed only with a checkpoint path)")
    if args.regime != WindUKF.schema:
        p.error(f"--checkpoint {name} with --regime {args.regime}: the UKF reads the {WindUKF.schema!r} features only "
                f"(allowed: --regime {WindUKF.schema}, or a {args.regime} checkpoint path)")


def model_based_estimator(name: str, regime: str, dataset_manifest: dict) -> tuple[WindEstimator, dict]:
    """The model-based estimator ``name`` on the dataset's own airframe (its model error is stated
    against it) and the manifest the tables describe it by."""
    estimator = load_estimator(regime, name, config=config_from_dict(EnvConfig, dataset_manifest["config"]))
    return estimator, {"model_based": type(estimator).__name__, "config": asdict(estimator.cfg)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--regime", required=True, choices=["horizontal", "vertical"])
    p.add_argument("--checkpoint", default=None,
                   help="default: the shipped quadwind_trl/checkpoints/estimator_<regime>.pt; 'ukf': the model-based "
                        "WindUKF (horizontal; outputs default to results/experiments/ukf/)")
    p.add_argument("--data", required=True, help="the training dataset (its held-out test cases are evaluated)")
    p.add_argument("--unseen-data", default=None, help="an independently generated dataset (disjoint LHS seed): all its flights")
    p.add_argument("--stride", type=int, default=1, help="samples between evaluated windows (1: every 10 Hz sample)")
    p.add_argument("--taus", type=float, nargs="+", default=list(TAU_SWEEP_S), help="EMA time constants to sweep (0 = raw)")
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--quick", action="store_true", help="the dataset is a --quick one (split in thirds if needed)")
    p.add_argument("--md", default=None,
                   help="section file (one section per regime); default docs/results/2_estimation.md, which recipes/report.py "
                        "merges into docs/results.md (--checkpoint ukf: results/experiments/ukf/estimation.md)")
    p.add_argument("--link-base", default=None,
                   help="figure links are relative to this folder; default docs, where docs/results.md is "
                        "(--checkpoint ukf: results/experiments/ukf)")
    p.add_argument("--fig-dir", default=None, help="default docs/figures (--checkpoint ukf: results/experiments/ukf/figures)")
    p.add_argument("--json", default=None,
                   help="default: results/estimation_<regime>.json "
                        "(--checkpoint ukf: results/experiments/ukf/estimation_<regime>.json)")
    p.add_argument("--update-checkpoint", action="store_true", help="record these metrics and the val-selected tau in the checkpoint's manifest")
    args = p.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    regime = args.regime
    model_based = args.checkpoint in MODEL_BASED_ESTIMATORS
    if model_based:
        refuse_model_based_misuse(p, args)
    ckpt = Path(args.checkpoint) if args.checkpoint else CHECKPOINT_DIR / f"estimator_{regime}.pt"
    json_path, md_path, fig_dir, link_base = output_paths(args, model_based)
    fig_dir.mkdir(parents=True, exist_ok=True)
    # the section file holds both regimes' sections: one writer at a time rewrites it
    hold_for_command(json_path, md_path, *([ckpt] if args.update_checkpoint else []), what="estimator evaluation output",
                     hint="wait for it to finish, or choose another --json / --md")
    t_start = time.perf_counter()

    if model_based:
        inputs = {}
    else:
        try:  # the checkpoint says which inputs it reads: the window length and the trailing means
            estimator = bundle = EstimatorBundle.load(ckpt)
            inputs = estimator_inputs(bundle)
        except (FileNotFoundError, ValueError) as err:
            p.error(str(err))
        if bundle.schema != regime:  # before the dataset's features are loaded or computed
            p.error(f"{ckpt} is a {bundle.schema!r} estimator, not {regime!r} (--regime)")
    try:
        ed = load_estimator_data(args.data, regime, quick=args.quick, **inputs)
    except (FileNotFoundError, ValueError) as err:
        p.error(str(err))
    if model_based:
        estimator, manifest = model_based_estimator(args.checkpoint, regime, ed.manifest)
    else:
        manifest = bundle.manifest
        trained_on = manifest.get("dataset", {}).get("manifest_sha256")
        if trained_on and trained_on != ed.info["manifest_sha256"]:
            print(f"WARNING: {ckpt} was trained on another dataset ({manifest['dataset'].get('path')}); "
                  "its test split may overlap training", flush=True)
    results: dict = {"regime": regime, "checkpoint": args.checkpoint if model_based else repo_relative(ckpt), "data": ed.info,
                     "stride": args.stride, "command": command_line(sys.argv), "git_commit": git_commit(), "platform": platform_info(),
                     "paper_tau_s": DEFAULT_TAU_S}  # fmt: skip
    if model_based:
        results["estimator"] = manifest
    unseen = None
    if args.unseen_data:
        try:
            unseen = load_estimator_data(args.unseen_data, regime, quick=args.quick, **inputs)
        except (FileNotFoundError, ValueError) as err:
            p.error(f"--unseen-data: {err}")
    run = run_estimation(estimator, ed, results, unseen=unseen, stride=args.stride, batch=args.batch, taus=args.taus,
                         paper_tau_s=DEFAULT_TAU_S)
    figs, case = estimation_figures(run, fig_dir)
    results["figures"] = {k: repo_relative(v) for k, v in figs.items()}
    results["example_case"] = case
    md = estimation_markdown(run, figs, args.checkpoint if model_based else ckpt, manifest, link_base, json_path)
    md_path.parent.mkdir(parents=True, exist_ok=True)
    replace_section(md_path, regime, md)
    results["wall_time_s"] = round(time.perf_counter() - t_start, 1)
    tmp = json_path.with_name(f".{json_path.name}.tmp")
    tmp.write_text(json.dumps(results, indent=1, default=float) + "\n")
    tmp.replace(json_path)

    t, tau_best = results["test"], run.tau_best
    if args.update_checkpoint:
        bundle.manifest["evaluation"] = {
            "command": results["command"],
            "stride": args.stride,
            "val_best_tau_s": tau_best,
            "test_raw": t["summary"],
            "test_ema": results["test_ema"],
            **({"unseen_raw": results["unseen"]["summary"], "unseen_ema": results["unseen_ema"]} if run.unseen is not None else {}),
        }
        bundle.save(ckpt)
        print(f"updated {ckpt}: evaluation metrics (validation-best tau {tau_best:g} s) in its manifest")
    s = t["summary"]
    print(
        f"test: per-window {s['per_window_vector_rmse']:.3f} m/s, per-flight {s.get('per_flight_vector_rmse', float('nan')):.3f} m/s, "
        f"component-mean {s['component_mean_rmse']:.3f} m/s, direction MAE {s['direction_mae_deg']:.2f} deg, corr {s['corr_n']:.4f}/{s['corr_e']:.4f}, "
        f"vector skill {s['vector_skill']:.3f}, speed skill {s['speed_skill']:.3f}; val best tau {tau_best:g} s"
    )
    print(f"wrote {md_path} ({regime} section), {json_path}, {len(figs)} figures in {fig_dir}; {results['wall_time_s']} s")


if __name__ == "__main__":
    main()
