"""The paired three-way ablation (plus true-wind oracles) on identical replayed physics.

Every controller flies the same scenarios, in an env of the same batch size, so each episode's
world (turbulence field, sensor noise and bias, initial state) is bitwise the same for all of
them (``docs/simulator.md``, exact replay; the flights go through
:func:`~quadwind_trl.rl.paired.fly_paired`, as the trainer's evaluation against PD does):

* ``pd``: the wind-blind PD baseline (zero residual); for a policy trained on another base
  controller (``--base-controller``), that base law alone;
* ``blind``: the trained policy with its two wind inputs forced to zero (``ZeroInputs``): the same
  weights, the wind channel removed at inference (the paper's "wind-blind RL");
* ``aware``: the trained policy reading the frozen estimator's filtered wind (the paper's system);
* ``oracle``: the same policy fed the true turbulence-free mean wind instead of the estimate
  (not in the paper: it measures what a perfect estimator would add);
* ``trained_blind``: a second policy, trained from scratch with its wind inputs zeroed
  (``--wind-input zero``) and flown that way (not in the paper: trained-blind vs wind-aware is the
  value of perception to a policy that could adapt to its absence, where zeroing the inputs of
  a policy trained with them also measures how much it leans on them);
* ``trained_oracle``: a third policy, trained with the true mean wind (``--wind-input truth``) and
  flown with it (not in the paper: trained-oracle vs trained-blind is what a perfect estimate is
  worth to a policy trained to use it);
* the classical base controllers (:data:`~quadwind_trl.regimes.CLASSICAL_CONTROLLERS`, not in the
  paper), flown with no policy in the same worlds: ``pid`` (the PD with integral action), ``dob``
  (a disturbance observer), ``pd_ff`` and ``pid_ff`` (wind feed-forward on the estimate the
  policy sees), their blind twins ``*_ff_blind`` (the same law with the estimate at zero) and
  oracles ``*_ff_oracle`` (the true mean wind): the strongest baseline a practitioner would fly,
  and what the estimate is worth to a controller that cannot learn.

Every policy flies with the env settings it trained with
(:func:`~quadwind_trl.rl.envs.policy_env_settings`), its ``zero_inputs`` included; ``blind`` adds
the wind channels to them. The separately trained policies must have trained on the same env
config and without the same inputs as the wind-aware one, so that only the wind input differs.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

import torch
from tensordict import TensorDict, TensorDictBase

from ..config import EnvConfig, config_from_dict
from ..envs.runner import FlightResults, NestedKey
from ..envs.trajectories import trajectory_ids, trajectory_name
from ..estimator import EstimatorBundle
from ..rl.envs import make_env, policy_env_settings
from ..rl.paired import fly_paired, improvement
from ..regimes import CLASSICAL_CONTROLLERS, classical_controller
from ..rl.policy import load_policy
from .grouping import summarize
from .phases import phase_columns
from .statistics import decompose, paired_summary

RL_CONTROLLERS = ("pd", "blind", "aware", "oracle", "trained_blind", "trained_oracle")
CONTROLLERS = RL_CONTROLLERS + CLASSICAL_CONTROLLERS
# PD ignores its observation: "truth" spares it the estimator (the physics is the same either way)
WIND_INPUT = {"pd": "truth", "blind": "zero", "aware": "estimate", "oracle": "truth", "trained_blind": "zero",
              "trained_oracle": "truth"}
# the controllers flown by their own, separately trained policy (trained with the wind input they
# fly with, WIND_INPUT) instead of the wind-aware one, and the key a results file records its path under
TRAINED_POLICY_KEYS = {"trained_blind": "blind_policy", "trained_oracle": "oracle_policy"}
TRACE_KEYS = (("truth", "pos"), "ref_pos", ("truth", "mean_wind"), "step")


def policy_env_config(payload: dict) -> EnvConfig:
    """The env config the policy was trained with (from its checkpoint)."""
    return config_from_dict(EnvConfig, payload["env_spec"]["env_config"])


def policy_compile_step(payload: dict) -> bool:
    """Whether the policy trained on the compiled simulator step (its checkpoint's env spec;
    policies saved before the RL stack compiled by default trained eagerly)."""
    return bool(payload["env_spec"].get("compile_step", False))


def fly_controllers(
    regime: str,
    scenarios: TensorDictBase,
    policy_path: str | Path,
    estimator: EstimatorBundle,
    controllers: tuple[str, ...] = CONTROLLERS,
    batch: int | None = None,
    progress: bool = False,
    device: str = "cpu",
    config_override: Callable[[EnvConfig], EnvConfig] | None = None,
    compile_step: bool | None = None,
    chunks: range | None = None,
    trained_policies: Mapping[str, str | Path] | None = None,
    log_keys: Sequence[NestedKey] = TRACE_KEYS,
    estimate_every_s: float | None = None,
) -> dict[str, FlightResults]:
    """Fly ``scenarios`` with each controller (:func:`~quadwind_trl.rl.paired.fly_paired`);
    results per controller, in scenario order.

    The env is the one the policy trained in (its config is in the checkpoint), unless
    ``config_override`` changes it (e.g. shorter flights for smoke runs). ``compile_step``
    (default: :func:`policy_compile_step`) chooses the compiled or the eager simulator step.
    ``batch`` episodes fly at once (default: all); ``chunks`` flies only those batches.
    ``trained_policies`` maps each controller of :data:`TRAINED_POLICY_KEYS` that is flown to its
    policy file (:func:`load_trained_policies` checks them). ``log_keys``:
    the entries of the 10 Hz flight record (default :data:`TRACE_KEYS`; any entry of the
    transformed env's step output, e.g. ``"observation"``, the policy's normalised input).
    ``estimate_every_s``: seconds between estimator queries (default: what each policy trained
    with, :func:`~quadwind_trl.rl.envs.policy_env_settings`)."""
    policies = {"aware": load_policy(policy_path, device=device)}
    _, payload = policies["aware"]
    policies.update(load_trained_policies(controllers, trained_policies or {}, policy_path, payload, device))
    config = policy_env_config(payload)
    if compile_step is None:
        compile_step = policy_compile_step(payload)
    if config_override is not None:
        config = config_override(config)
    n = batch or scenarios.batch_size[0]

    def flight(name: str):
        actor, inputs = policies[name if name in TRAINED_POLICY_KEYS else "aware"]
        settings = policy_env_settings(inputs["env_spec"], estimator)
        if estimate_every_s is not None:
            settings["estimate_every_s"] = estimate_every_s
        if name in CLASSICAL_CONTROLLERS:  # the base law alone, on the estimate the policy sees (or none)
            law, base_wind = classical_controller(regime, name)
            settings["base_wind_input"] = base_wind
            # no policy reads this env's observation: the policy's own inputs (its base law's state, its
            # memory, its normalisation) may not exist on this law, and would change nothing flown
            for key in ("base_state_inputs", "preview_inputs", "memory_frames", "recurrent_hidden"):
                settings.pop(key)
            flown = replace(config, controller=replace(config.controller, **law))
            env = make_env(regime, estimator if base_wind == "estimate" else None, n,
                           wind_input="estimate" if base_wind == "estimate" else "truth", device=device, config=flown,
                           compile_step=compile_step, **settings)
            return env, None
        wind_input = WIND_INPUT[name]
        if config.controller.needs_wind and settings["base_wind_input"] == "estimate" and wind_input == "truth":
            if name == "pd":  # the residual's own base law, on the estimate it trained on
                wind_input = "estimate"
            else:  # a policy flown on the true wind runs no estimator: its feed-forward base flies the truth too
                settings["base_wind_input"] = "truth"
        # "blind" is the aware policy with wind_input="zero": its wind channels join its zero_inputs
        env = make_env(regime, estimator if wind_input != "truth" else None, n, wind_input=wind_input,
                       device=device, config=config, vecnorm_state=inputs["vecnorm"], compile_step=compile_step, **settings)
        return env, None if name == "pd" else actor

    flights = {name: flight(name) for name in controllers}
    return fly_paired(flights, scenarios, log_keys=log_keys, progress=progress, chunks=chunks)


def load_trained_policies(controllers: Sequence[str], paths: Mapping[str, str | Path], aware_path: str | Path,
                          aware_payload: dict, device: str = "cpu") -> dict[str, tuple]:
    """``{controller: (actor, payload)}`` for each flown controller of :data:`TRAINED_POLICY_KEYS`,
    from ``paths`` (checked by :func:`check_trained_policy`)."""
    unknown = sorted(set(paths) - set(TRAINED_POLICY_KEYS))
    if unknown:
        raise ValueError(f"trained_policies: unknown controllers {unknown}; allowed: {sorted(TRAINED_POLICY_KEYS)}")
    policies = {}
    for name in (c for c in controllers if c in TRAINED_POLICY_KEYS):
        if paths.get(name) is None:
            raise ValueError(f"controller {name!r} needs trained_policies[{name!r}]: a policy trained with "
                             f"--wind-input {WIND_INPUT[name]}")
        policies[name] = load_policy(paths[name], device=device)
        check_trained_policy(name, paths[name], policies[name][1], aware_path, aware_payload)
    return policies


def check_trained_policy(name: str, path: str | Path, payload: dict, aware_path: str | Path, aware_payload: dict) -> None:
    """A ``ValueError`` naming the controller, the path and the value unless the policy of
    controller ``name`` trained with the wind input it flies with, on the wind-aware policy's env
    config (the same worlds) and without the same inputs (only the wind input differs)."""
    wind_input = WIND_INPUT[name]
    trained_with = payload["env_spec"].get("wind_input")
    if trained_with != wind_input:
        raise ValueError(f"trained_policies[{name!r}]={path} trained with wind_input={trained_with!r}; "
                         f"a {name} policy trains with {wind_input!r} (--wind-input {wind_input})")
    if policy_env_config(payload) != policy_env_config(aware_payload):
        raise ValueError(f"trained_policies[{name!r}]={path} trained on another env config than {aware_path}: "
                         "their episodes would not be the same worlds")
    zeroed, aware_zeroed = (policy_env_settings(p["env_spec"], None)["zero_inputs"] for p in (payload, aware_payload))
    if set(zeroed) != set(aware_zeroed):  # the order they were named in changes nothing
        raise ValueError(f"trained_policies[{name!r}]={path} trained with zero_inputs={zeroed}, {aware_path} with "
                         f"{aware_zeroed}: the comparison would change more than the wind input")


def episode_table(scenarios: TensorDictBase, results: dict[str, FlightResults],
                  pattern_start: torch.Tensor | None = None) -> TensorDict:
    """``[episodes]`` table of each episode's world (trajectory, wind, intensity, case) and every
    controller's RMSEs and crash flag, keyed ``<controller>_<metric>``. Given each episode's
    ``pattern_start`` (:func:`~quadwind_trl.evaluation.phases.pattern_starts`) and flight records
    with :data:`TRACE_KEYS`, also the horizontal error per flight phase
    (:func:`~quadwind_trl.evaluation.phases.phase_columns`: ``<controller>_sse_xy_<phase>`` and
    ``<controller>_samples_<phase>``)."""
    table = scenarios.select("traj_id", "wind_speed_ref_m_s", "turb_intensity", "case_id", strict=False).clone()
    for name, res in results.items():
        table[f"{name}_rmse_xy"] = res.rmse_xy
        table[f"{name}_rmse_z"] = res.rmse_z
        table[f"{name}_rmse"] = res.rmse
        table[f"{name}_crashed"] = res.crashed
        if pattern_start is not None:
            table.update({f"{name}_{key}": column for key, column in phase_columns(res, pattern_start).items()})
    return table


def episode_table_from_json(episodes: dict[str, list]) -> TensorDict:
    """The :func:`episode_table` a results file persisted (its ``episodes_table``), exactly: every
    RMSE was a float32, which a JSON double holds without rounding."""
    columns = dict(episodes)
    table = TensorDict({"traj_id": trajectory_ids(columns.pop("trajectory"))}, batch_size=[len(columns["case_id"])])
    for key, values in columns.items():
        dtype = torch.bool if key.endswith("_crashed") else torch.int64 if key == "case_id" else torch.float32
        table[key] = torch.tensor(values, dtype=dtype)
    return table


def _grouped_decomposition(table: TensorDictBase, metric: str, labels: torch.Tensor) -> dict:
    out = {}
    for label in labels.unique(sorted=True).tolist():
        m = labels == label
        aware = table[f"aware_{metric}"][m]
        d = decompose(table[f"pd_{metric}"][m], table[f"blind_{metric}"][m], aware)
        row = d.as_dict()
        for name in ("oracle", "trained_blind", "trained_oracle"):
            if f"{name}_{metric}" in table.keys():
                row[name] = table[f"{name}_{metric}"][m].double().mean().item()
        if f"trained_blind_{metric}" in table.keys():
            trained_blind = table[f"trained_blind_{metric}"][m]
            # the value of perception between two trained policies: % of the trained-blind
            # policy's RMSE the wind-aware one removes (positive: the estimate helps)
            row["trained_perception"] = improvement(trained_blind, aware)
            if f"trained_oracle_{metric}" in table.keys():
                # the same for a perfect estimate, to a policy trained to use it
                row["trained_oracle_perception"] = improvement(trained_blind, table[f"trained_oracle_{metric}"][m])
        out[label] = row
    return out


def feedforward_comparisons(controllers: Sequence[str]) -> dict[tuple[str, str], tuple[str, str]]:
    """``(law, value) -> (baseline, other)`` for each wind feed-forward law among ``controllers``
    whose twin flew too, paired with ``other`` better when positive: ``estimate_value``, the law
    on the estimate against its blind twin (what the estimate is worth to a law that cannot
    learn), and ``oracle_value``, the law on the true wind against the estimate (what a perfect
    estimate would add)."""
    flown = set(controllers)
    out = {}
    for law in ("pd_ff", "pid_ff"):
        if {law, f"{law}_blind"} <= flown:
            out[(law, "estimate_value")] = (f"{law}_blind", law)
        if {law, f"{law}_oracle"} <= flown:
            out[(law, "oracle_value")] = (law, f"{law}_oracle")
    return out


def summarize_ablation(sweep_name: str, table: TensorDictBase, controllers: Sequence[str]) -> dict:
    """Everything the paper's tables need, JSON-ready, from an :func:`episode_table`: paired
    statistics of each policy variant against PD, the decomposition by wind level and by
    trajectory, and per-episode RMSEs; for both axes on every sweep (a horizontal policy that
    tracks xy better by losing height must show it)."""
    names = list(controllers)
    summary: dict = {"sweep": sweep_name, "episodes": table.batch_size[0], "controllers": names}
    for metric in ("rmse_xy", "rmse_z", "rmse"):
        block: dict = {}
        for name in names:
            if name != "pd":
                block[name] = paired_summary(table[f"pd_{metric}"], table[f"{name}_{metric}"])
            stats = summarize(table[f"{name}_{metric}"])
            block.setdefault("distribution", {})[name] = stats.as_dict()
        if {"trained_blind", "aware"} <= set(names):
            # aware vs the policy trained without wind inputs: perception's value, paired
            block["trained_perception"] = paired_summary(table[f"trained_blind_{metric}"], table[f"aware_{metric}"])
        classical = [c for c in names if c in CLASSICAL_CONTROLLERS]
        if "aware" in names and classical:
            # the wind-aware policy against each classical controller, paired (positive: RL better)
            block["aware_vs_classical"] = {c: paired_summary(table[f"{c}_{metric}"], table[f"aware_{metric}"])
                                           for c in classical}
        for (law, key), (baseline, other) in feedforward_comparisons(names).items():
            block.setdefault("feedforward", {}).setdefault(law, {})[key] = paired_summary(
                table[f"{baseline}_{metric}"], table[f"{other}_{metric}"])
        if {"trained_blind", "trained_oracle"} <= set(names):
            # the policy trained on the true wind vs the one trained without: a perfect estimate's value
            block["trained_oracle_vs_trained_blind"] = paired_summary(table[f"trained_blind_{metric}"],
                                                                      table[f"trained_oracle_{metric}"])
        if {"pd", "blind", "aware"} <= set(names):
            block["decomposition"] = decompose(table[f"pd_{metric}"], table[f"blind_{metric}"], table[f"aware_{metric}"]).as_dict()
            block["by_wind"] = {f"{k:g}": v for k, v in _grouped_decomposition(table, metric, table["wind_speed_ref_m_s"]).items()}
            block["by_trajectory"] = {
                trajectory_name(k): v for k, v in _grouped_decomposition(table, metric, table["traj_id"]).items()
            }
        block["median"] = {name: table[f"{name}_{metric}"].median().item() for name in names}
        block["worst"] = {name: table[f"{name}_{metric}"].max().item() for name in names}
        summary[metric] = block
    summary["crashed"] = {name: int(table[f"{name}_crashed"].sum()) for name in names}
    episodes = {key: table[key].tolist() for key in table.keys()}
    # persisted by name: an id is only a position in this process's registry
    episodes["trajectory"] = [trajectory_name(i) for i in episodes.pop("traj_id")]
    summary["episodes_table"] = episodes
    return summary
