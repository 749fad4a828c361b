"""The validation search for the classical base controllers' gains and filter constants.

Each candidate is a :class:`~quadwind_trl.config.ControllerConfig` of one family (one
disturbance model, with or without integral action), and a family flies in one batch: every
candidate flies its own copy of the regime's validation sweep
(:func:`~quadwind_trl.rl.paired.validation_scenarios`), and the law's constants are per-row
tensors (:func:`per_row_controller`), so ``K`` candidates cost one batched flight of ``K x 45`` rows
rather than ``K`` flights. Each row's world is its scenario's (exact replay); a row's physics
agrees with the same scenario flown alone to float rounding (another batch layout), which is
what a search needs, and the chosen values are then flown on the test sweeps in the ablation's
own layout.

A candidate is scored as the trainer scores a policy (:func:`~quadwind_trl.rl.paired.validation_score`:
the mean episode RMSE plus the mean of its worst tenth), and the search keeps the lowest score
among the candidates that crash no more often than PD (:func:`select_candidate`): a crash ends an
episode early, and its RMSE over the part flown can be lower than a whole flight's, so the score
alone can prefer a gain that loses the vehicle.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import torch
from tensordict import TensorDictBase

from ..config import ControllerConfig, EnvConfig
from ..envs.controller import CascadeController, ClassicalParams, ControllerParams
from ..estimator import WindEstimator
from ..envs.runner import flight_order, fly
from ..evaluation.ablation import policy_compile_step, policy_env_config
from ..manifest import CHECKPOINT_DIR
from ..quick import SWEEP_QUICK
from ..regimes import VALIDATION_SWEEPS
from ..rl.envs import RLEnvSpec, WindInput, build_env
from ..rl.paired import improvement, validation_scenarios, validation_score, win_rate
from ..rl.policy import load_policy
from .section import ReportContext, Section
from .tables import seed_stats
from .training import on_paper_pd




def validation_setup(regime: str, quick: bool = False, compile_step: bool | None = None
                     ) -> tuple[EnvConfig, TensorDictBase, bool, dict]:
    """What a classical law flies in on validation: the env config the regime's shipped policy
    trained in (its sensing, flights and estimate; the quick sweep's short flights under
    ``quick``), the validation sweep (three episodes under ``quick``), whether the step is
    compiled (``compile_step`` None: as the policy trained, eager under ``quick``), and the
    policy file's payload."""
    _, payload = load_policy(CHECKPOINT_DIR / f"policy_{regime}.pt")
    config = policy_env_config(payload)
    scenarios = validation_scenarios(regime, 3 if quick else None)
    if quick:
        config = SWEEP_QUICK.config(config)
        scenarios = SWEEP_QUICK.scenarios(scenarios, VALIDATION_SWEEPS[regime].ranges.top_altitude_m)
    if compile_step is None:
        compile_step = not quick and policy_compile_step(payload)
    return config, scenarios, compile_step, payload


def _batch(c: ControllerConfig) -> tuple:
    """What the candidates of one batch share: the outer loop and what the law reads (a
    simulator's settings, one per env); the rest are per-row constants (:func:`per_row_controller`)."""
    return c.kp_pos, c.kd_pos, c.max_tilt_deg, c.pos_error_limit_m, c.feedback, c.observer_reads


def per_row_controller(candidates: Sequence[ControllerConfig], row_candidate: torch.Tensor, config: EnvConfig,
                       device: torch.device | str = "cpu") -> CascadeController:
    """One :class:`CascadeController` whose env row ``i`` flies ``candidates[row_candidate[i]]``:
    their integral gain and limit, observer filter gain and inner-loop (attitude and rate) gains as
    per-row tensors. The candidates must be of one family (the same disturbance model; a candidate
    without integral action is the family's ``Ki = 0`` row) and share the outer loop's PD gains."""
    if not candidates:
        raise ValueError("per_row_controller: no candidates")
    families = sorted({c.disturbance for c in candidates})
    if len(families) > 1:
        raise ValueError(f"per_row_controller: candidates of one disturbance model only; got {families}")
    if len({_batch(c) for c in candidates}) > 1:
        raise ValueError("per_row_controller: the candidates differ in their outer loop or in what they read; only "
                         "the classical additions and the inner loop's gains may")
    dt = config.timing.control_dt_s
    extras = [ClassicalParams.from_config(c, config.vehicle, dt, device) for c in candidates]

    def rows(values: list[torch.Tensor]) -> torch.Tensor:
        return torch.stack(values)[row_candidate.to(device)]

    first = extras[0]
    extra = replace(
        first,
        ki=None if all(e.ki is None for e in extras) else rows([torch.zeros(3, device=device) if e.ki is None else e.ki
                                                                for e in extras]),
        integral_limit=rows([e.integral_limit for e in extras]),
        observer_gain=rows([torch.tensor([e.observer_gain], device=device) for e in extras]),
    )
    inner = [ControllerParams.from_config(c, config.vehicle, device) for c in candidates]
    pd = replace(inner[0], k_att=rows([p.k_att for p in inner]), k_rate=rows([p.k_rate for p in inner]))
    return CascadeController(pd, extra)


@dataclass(frozen=True)
class CandidateResult:
    """One candidate's validation flights against the PD that flew the same episodes."""

    controller: ControllerConfig
    rmse_xy: torch.Tensor  # [M] per validation episode, m
    rmse_z: torch.Tensor
    crashed: torch.Tensor

    @property
    def rmse(self) -> torch.Tensor:
        return torch.sqrt(self.rmse_xy**2 + self.rmse_z**2)

    def row(self, pd: "CandidateResult") -> dict:
        """The search table's row: the score, the means, and the gains over PD (%; wins of ``M``)."""
        wins, pairs = win_rate(pd.rmse, self.rmse)
        return {
            "validation_score": validation_score(self.rmse),
            "rmse_xy": float(self.rmse_xy.double().mean()),
            "rmse_z": float(self.rmse_z.double().mean()),
            "improvement_xy_pct": improvement(pd.rmse_xy, self.rmse_xy),
            "improvement_z_pct": improvement(pd.rmse_z, self.rmse_z),
            "wins": wins,
            "episodes": pairs,
            "crashed": int(self.crashed.sum()),
        }


def fly_candidates(
    regime: str,
    candidates: Sequence[ControllerConfig],
    scenarios: TensorDictBase,
    estimator: WindEstimator | None = None,
    *,
    base_wind_input: WindInput = "estimate",
    config: EnvConfig | None = None,
    spec_settings: dict | None = None,
    device: str = "cpu",
    compile_step: bool = False,
    progress: bool = False,
) -> list[CandidateResult]:
    """Every candidate (one family) flown on ``scenarios``; results in candidate order. Candidates
    that differ only in per-row constants (the integral, the observer's filter, the inner loop's
    gains) fly in one batch; those that differ in the outer loop (e.g. the tilt limit) or in what
    the law reads fly in a batch each.

    ``config``: the env config the candidates replace the controller of (default: the regime's).
    ``base_wind_input``: what a wind feed-forward family flies on (``RLEnvSpec.base_wind_input``;
    ``"estimate"`` needs ``estimator``). ``spec_settings``: other :class:`~quadwind_trl.rl.envs.RLEnvSpec`
    fields (the estimate's ``ema_tau_s`` and ``estimate_every_s``)."""
    batches: dict[tuple, list[int]] = {}
    for i, c in enumerate(candidates):
        batches.setdefault(_batch(c), []).append(i)
    results: dict[int, CandidateResult] = {}
    m = scenarios.batch_size[0]
    for members in batches.values():
        batch = [candidates[i] for i in members]
        spec = RLEnvSpec(regime=regime, num_envs=m * len(batch), device=device, compile_step=compile_step,
                         wind_input="estimate" if base_wind_input == "estimate" else "truth",
                         base_wind_input=base_wind_input, config=replace(config or RLEnvSpec(regime).env_config,
                                                                         controller=batch[0]),
                         **(spec_settings or {}))
        flights = torch.cat([scenarios] * len(batch))  # candidate-major: row i is candidate i // m's
        # the runner flies the rows longest first: env row j flies flight order[j]
        order, _ = flight_order(spec.env_config, flights, device)
        controller = per_row_controller(batch, order // m, spec.env_config, device)
        env = build_env(spec, estimator, controller=controller, freeze_norm=True)
        res = fly(env, flights, progress=progress)
        results.update({i: CandidateResult(c, res.rmse_xy[k * m:(k + 1) * m], res.rmse_z[k * m:(k + 1) * m],
                                           res.crashed[k * m:(k + 1) * m]) for k, (i, c) in enumerate(zip(members, batch))})
    return [results[i] for i in range(len(candidates))]


def select_candidate(rows: Sequence[dict], pd_crashed: int) -> dict:
    """The search table's row a family keeps: the lowest ``validation_score`` among the rows that
    crashed no more often than PD (all rows, if every one did)."""
    safe = [r for r in rows if r["crashed"] <= pd_crashed] or list(rows)
    return min(safe, key=lambda r: r["validation_score"])


FAMILY_LABEL = {"pid": "PD + integral (PID)", "dob": "PD + disturbance observer", "l1": "PD + L1 adaptive",
                "pid_ff": "PD + integral + wind feed-forward", "dob_inner": "PD + disturbance observer, stiffer inner loop",
                "dob_inner_tilt": "PD + disturbance observer, stiffer inner loop: the tilt limit"}
FIELD_LABEL = {"ki_pos": "K_i (1/s^3)", "observer_tau_s": "tau (s)", "k_att": "K_R roll (N m/rad; K_omega x sqrt)",
               "max_tilt_deg": "commanded-tilt limit (deg)"}
POLICY_KINDS = (("wind-aware RL", "estimate"), ("trained-blind RL", "zero"), ("trained-oracle RL", "truth"))


def _searched(value) -> str:
    return f"{value[0]:g}" if isinstance(value, list) else f"{value:g}"


def classical_section(searches: dict[str, dict], manifests: dict[str, dict]) -> str:
    """"Against classical controllers": each regime's validation search
    (``results/base_search_<regime>.json``, recipes/tune_base_controllers.py), every candidate
    against PD on the validation sweep, beside the PPO seeds' own validation evaluations against
    the same PD on the same episodes (their kept policies' manifests)."""
    lines = ["## Against classical controllers", "",
             "The paper's PD has no integral action. The classical controllers a practitioner would fly (PD with integral",
             "action, a disturbance observer, L1 adaptive control, wind feed-forward on the estimate; docs/simulator.md,",
             "\"Classical base controllers\") are tuned here on each regime's validation sweep, scored as the trainer",
             "scores a policy (mean RMSE plus the mean of the worst tenth, lower is better; a family keeps its best",
             "candidate among those that crash no more often than PD). Beside them, the PPO seeds' own evaluations on the",
             "same validation episodes against the same PD (their kept checkpoints). These are validation flights, the",
             "flights choices are made on; the test sweeps' rows come from the paired ablation. A family's candidates",
             "fly in one batch, so its `K_i = 0` row is PD (or PD with feed-forward alone) in another batch layout: equal",
             "to PD to float rounding, which is all its few \"wins\" are.", ""]
    for regime, search in searches.items():
        pd = search["pd"]
        lines += [f"### {regime.capitalize()} validation sweep ({search['episodes']} episodes)", "",
                  f"`{search['command']}` at `{search['git_commit']}`, "
                  f"{'compiled' if search.get('compile_step') else 'eager'} step. PD: xy {pd['rmse_xy']:.3f} m, "
                  f"z {pd['rmse_z']:.3f} m, score {pd['validation_score']:.3f} m."]
        others = {family: block for family, block in search["families"].items()
                  if block.get("git_commit", search["git_commit"]) != search["git_commit"]}
        if others:  # families a later run flew beside the file's (the same env and episodes)
            lines.append("Flown by another run: " + "; ".join(f"{FAMILY_LABEL.get(f, f)}: `{b['command']}` at `{b['git_commit']}`"
                                                              for f, b in others.items()) + ".")
        lines += ["",
                  "| controller | searched value | score (m) | xy RMSE (m) | xy vs PD | z RMSE (m) | z vs PD | wins | crashed |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for family, block in search["families"].items():
            label = FAMILY_LABEL.get(family, family)
            kept = select_candidate(block["candidates"], pd["crashed"])
            for row in block["candidates"]:
                chosen = " **(chosen)**" if row is kept else ""
                lines.append(f"| {label} | {FIELD_LABEL.get(block['field'], block['field'])} = {_searched(row['value'])}{chosen} | "
                             f"{row['validation_score']:.3f} | {row['rmse_xy']:.3f} | {row['improvement_xy_pct']:+.1f} % | "
                             f"{row['rmse_z']:.3f} | {row['improvement_z_pct']:+.1f} % | {row['wins']}/{row['episodes']} | "
                             f"{row['crashed']} |")
        runs = {kind: [m["metrics"] for name, m in manifests.items() if name.startswith(f"ppo_{regime}") and on_paper_pd(m)
                       and m.get("env_spec", {}).get("wind_input") == wind and m.get("metrics")] for kind, wind in POLICY_KINDS}
        runs = {kind: ms for kind, ms in runs.items() if ms}
        if runs:
            lines += ["", "| PPO seeds (kept policies) | seeds | score (m): mean (range) | xy vs PD: mean (range) | "
                      "z vs PD: mean (range) | crashed (sum) |", "|---|---|---|---|---|---|"]
            for kind, ms in runs.items():
                scores = [m["validation_score"] for m in ms]
                lines.append(f"| {kind} | {len(ms)} | {sum(scores) / len(scores):.3f} ({min(scores):.3f} to {max(scores):.3f}) | "
                             f"{seed_stats([m['improvement_rmse_xy_pct'] for m in ms])} | "
                             f"{seed_stats([m['improvement_rmse_z_pct'] for m in ms])} | {sum(m['crashed'] for m in ms)} |")
        lines.append("")
    return "\n".join(lines)


def _render(ctx: ReportContext) -> str | None:
    return classical_section(ctx.searches, dict(ctx.manifests)) if ctx.searches else None


SECTION = Section("classical_search", "Against classical controllers", ("results/base_search_*.json",), _render)
