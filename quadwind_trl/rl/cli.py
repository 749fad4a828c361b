"""What the two PPO recipes share: their arguments, the ``--quick`` configuration, and the run.

The recipes (``recipes/ppo_horizontal.py``, ``recipes/ppo_vertical_curriculum.py``) only call
:func:`build_parser` and :func:`run`; nothing here reads ``sys.argv`` by itself.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import torch

from ..config import RESIDUAL_TARGETS, SENSING, EnvConfig, ResidualConfig, with_sensing
from ..estimator import DEFAULT_TAU_S, default_estimator_path, load_estimator
from ..keys import BASE_STATE_GROUPS, INPUT_GROUPS, PREVIEW_GROUPS, PRIVILEGED_GROUPS, input_channels
from ..quick import PPO_QUICK
from ..ray_cluster import RayUnavailable
from ..regimes import CLASSICAL_CONTROLLERS, PAPER_REWARD_W_Z, REWARD_W_Z, classical_controller, regime_config
from .collection import check_device, check_ray
from .config import COLLECTORS, LR_SCHEDULES, REWARD_SCALINGS, PPOConfig, vertical_curriculum
from .envs import DEFAULT_RANGES, RLEnvSpec, recipe_estimate_every_s, validated_tau_s
from .paired import validation_scenarios
from .policy import check_recurrent
from .trainer import PPOTrainer, ResumeMismatch

# frames between evaluations on the validation sweep, whose best one is kept: every 16 (horizontal)
# and 24 (vertical) batches of 16,384, 5 and 3 evaluations in a 1.5M-frame run, plus the last one.
# A horizontal evaluation (45 episodes, 2,174 decisions) took 35-38 s after the first (which also
# compiles and flies PD: ~150 s) on this 2-core machine
DEFAULT_EVAL_EVERY = {"horizontal": 262_144, "vertical": 393_216}
# the recipes evaluate in a second process while training goes on (PPOConfig.background_eval): they
# train on one thread, so on a machine of two cores or more the evaluations stop costing wall time
# (docs/benchmarks.md, "Time to a good policy": the same policy known 1.52x sooner). PPOConfig keeps
# False for library use: a spawned process re-imports a script that lacks a __main__ guard
DEFAULT_BACKGROUND_EVAL = True


def build_parser(regime: str, description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="tiny smoke run (seconds): short flights, few envs and frames")
    p.add_argument("--estimator", default=None,
                   help=f"estimator checkpoint (default: the shipped {default_estimator_path(regime)})")
    p.add_argument("--untrained-estimator", action="store_true",
                   help="use a seeded random estimator when no checkpoint is given (smoke tests only)")
    p.add_argument("--total-frames", type=int, default=None, help="policy decisions (env steps, 0.1 s of flight each) to train for (default 1,500,000)")
    p.add_argument("--num-envs", type=int, default=None, help="parallel sub-envs (default 64)")
    p.add_argument("--steps-per-env", type=int, default=None,
                   help="steps per sub-env per batch (default 256: 64 x 256 = 16384 = the paper's 8 envs x 2048)")
    p.add_argument("--lr-schedule", default=None, choices=list(LR_SCHEDULES),
                   help=f"learning rate over the run: linear decay from 3e-4 to 0 (default: {PPOConfig.lr_schedule}, "
                        "chosen by experiment, docs/rl.md 'Choosing the training recipe') or constant 3e-4 (the paper)")
    p.add_argument("--reward-scaling", default=None, choices=list(REWARD_SCALINGS),
                   help="none (the paper, default) or return_std: rewards divided by the running std of the discounted "
                        "return in the PPO update (a recipe candidate; evaluation is unchanged)")
    p.add_argument("--value-norm", action="store_true", default=None,
                   help="the critic learns its targets standardised by their running mean and std, rescaled to returns "
                        "for GAE (PopArt-style; default: off, the paper's critic on the return scale)")
    p.add_argument("--init-scale", type=float, default=None, metavar="STD",
                   help=f"the policy's initial exploration scale, the state-independent std of the pre-tanh Normal "
                        f"(default {PPOConfig.init_scale:g}; it is learned, but moves little over a run: docs/rl.md)")
    p.add_argument("--reward-w-z", type=reward_weight, default=None, metavar="BETA",
                   help=f"the reward's height-error weight beta (default the regime's: {REWARD_W_Z[regime]:g}; the paper's: "
                        f"{PAPER_REWARD_W_Z[regime]:g}; regimes.REWARD_W_Z says why they differ); recorded in the "
                        "policy's env config, so evaluation flies the same physics")
    p.add_argument("--out", default=None, help=f"run directory (default runs/ppo_{regime}[_quick])")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its latest checkpoint")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    p.add_argument("--collect-workers", type=int, default=None,
                   help="collection processes, one single-threaded simulator per core, each stepping num_envs / W rows "
                        "(default 1; the rows fly the same episodes whatever W: a speed setting, which --resume may change)")
    p.add_argument("--collector", default=None, choices=list(COLLECTORS),
                   help="where the rows are stepped: local (this machine: one process, or --collect-workers; default) "
                        "or ray (--num-collectors Ray actors of num_envs / K rows each, on a local Ray instance or the "
                        "cluster at --address; the policy and the normalisation stay in this process, and the batches "
                        "are those of --collect-workers K, bit for bit: a speed setting, which --resume may change; "
                        "docs/scaling.md)")
    p.add_argument("--num-collectors", type=int, default=None, metavar="K",
                   help="--collector ray: Ray actors stepping num_envs / K rows each, 1 CPU apiece (default 1)")
    p.add_argument("--address", default=None, metavar="auto|HOST:PORT",
                   help="--collector ray: the Ray cluster (auto: the one 'ray start' joined on this machine, or "
                        "RAY_ADDRESS; HOST:PORT: its head node); default: a local Ray instance of K CPUs for the run")
    p.add_argument("--background-eval", action=argparse.BooleanOptionalAction, default=None,
                   help="fly the periodic evaluations in a second process while training goes on (the same metrics and "
                        f"kept policy; a speed setting, which --resume may change; default: {DEFAULT_BACKGROUND_EVAL}, "
                        "except at --quick, whose one short evaluation costs less than starting that process)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", help="torch device of the simulator, estimator and networks (cpu, cuda, ...)")
    p.add_argument("--ema-tau-s", type=float, default=None,
                   help="time constant (s) of the EMA on the wind estimate the policy sees, 0: unfiltered (default: the "
                        f"one chosen on the estimator's validation flights, recorded in its manifest; else {DEFAULT_TAU_S})")
    p.add_argument("--estimate-every-s", type=float, default=None,
                   help="seconds between a sub-env's wind-estimator queries, a whole multiple of the 0.1 s log interval; "
                        "the estimate is held in between and the EMA keeps its time constant (default: the largest "
                        "multiple at or below tau / 30, e.g. 1 s at tau = 30 s; docs/rl.md, 'How often the estimator runs')")
    p.add_argument("--eager", action="store_true",
                   help="fly the simulator eagerly instead of through torch.compile (the default: compiled; --quick is eager)")
    p.add_argument("--wind-input", default="estimate", choices=["estimate", "zero", "truth"],
                   help="what the policy's wind channels carry during training (paper: estimate)")
    groups = "; ".join(f"{name}: {' '.join(channels)}" for name, channels in INPUT_GROUPS.items())
    p.add_argument("--zero-inputs", nargs="+", default=[], metavar="GROUP_OR_CHANNEL",
                   help=f"policy inputs forced to 0 in training and whenever the policy flies: groups ({groups}) or "
                        "channel names (keys.OBSERVATION_CHANNELS, the wind's excepted: --wind-input zero); default: none")
    base_groups = "; ".join(f"{name}: {' '.join(channels)}" for name, channels in BASE_STATE_GROUPS.items())
    p.add_argument("--base-state-inputs", nargs="+", default=[], metavar="GROUP_OR_CHANNEL",
                   help=f"the base controller's state the policy reads beside its 23 inputs, in training and whenever it "
                        f"flies: groups ({base_groups}) or channel names, those the --base-controller has (dob, l1: force "
                        "thrust ff; l1 also vel_err; pid: integral ff), or all: every one it has; default: none")
    p.add_argument("--preview-inputs", nargs="+", default=[], metavar="GROUP_OR_CHANNEL",
                   help=f"the reference ahead the policy reads after those, in training and whenever it flies: where the "
                        f"reference will be from the vehicle, groups ({' '.join(PREVIEW_GROUPS)}: 0.5, 1 and 2 s from now) "
                        "or channel names (keys.PREVIEW_CHANNELS); default: none")
    priv_groups = "; ".join(f"{name}: {' '.join(channels)}" for name, channels in PRIVILEGED_GROUPS.items())
    p.add_argument("--privileged-inputs", nargs="+", default=[], metavar="GROUP_OR_CHANNEL",
                   help=f"simulator truth the critic alone reads, at training time only (an asymmetric actor-critic; the "
                        f"policy flies without it): groups ({priv_groups}) or channel names; default: none")
    p.add_argument("--memory-frames", type=int, default=1, metavar="K",
                   help="the policy reads its last K observations (decisions) side by side, in training and whenever "
                        "it flies; K >= 1 (default 1: memoryless, the paper's)")
    p.add_argument("--recurrent-hidden", type=int, default=0, metavar="H",
                   help="a recurrent actor: a GRU of H units over the observations before its MLP, its hidden state "
                        "carried between decisions and restarted with each episode; needs the minibatch (512) a multiple of "
                        "--steps-per-env and local collection in this process (default 0: none)")
    p.add_argument("--eval-every", type=int, default=None,
                   help=f"frames between evaluations against PD, 0: only at the end (default {DEFAULT_EVAL_EVERY[regime]:,})")
    p.add_argument("--eval-episodes", type=int, default=None,
                   help="episodes of the validation sweep each evaluation flies (an even spread), 0: none, and the "
                        "run keeps its last iterate (default: all of them; --quick: 1)")
    p.add_argument("--sensing", default="navigation", choices=list(SENSING),
                   help="what the PD flies on (config.with_sensing): the nav filter as shipped (default), the same "
                        "sensors without bias walks, or the true state; an experiment, not the paper's vehicle")
    p.add_argument("--base-controller", default="pd", choices=("pd",) + CLASSICAL_CONTROLLERS,
                   help="the law the residual is added to (default: the paper's PD); a classical one "
                        "(regimes.CLASSICAL_CONTROLLERS) with the constants its validation search chose for the regime")
    p.add_argument("--residual-on", default=ResidualConfig.acts_on, choices=list(RESIDUAL_TARGETS),
                   help="where the residual acts (ResidualConfig.acts_on): wrench (the paper's: thrust and torques "
                        "added to the base law's output) or acceleration (forward, left, up, in m/s^2, added to the "
                        "base law's desired acceleration before its tilt limit, where the disturbance observer "
                        "corrects; "
                        "docs/rl.md, 'The residual on the outer loop'); recorded in the policy's env config; "
                        f"default: {ResidualConfig.acts_on}")
    p.add_argument("--logger", default="csv", choices=["csv", "tensorboard"])
    p.add_argument("--no-progress", action="store_true")
    return p


def with_base_controller(regime: str, config: EnvConfig, name: str) -> tuple[EnvConfig, str]:
    """``(config, base wind input)``: ``config`` with the base controller ``name`` ("pd": as it is)."""
    if name == "pd":
        return config, "estimate"
    law, base_wind = classical_controller(regime, name)
    return replace(config, controller=replace(config.controller, **law)), base_wind


def reward_weight(text: str) -> float:
    """A reward weight from the command line: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--reward-w-z={text!r}: expected a number >= 0") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"--reward-w-z={text}: allowed range: finite, >= 0")
    return value


def quick_setup(regime: str, spec: RLEnvSpec) -> tuple[RLEnvSpec, PPOConfig, list[str]]:
    """The ``--quick`` run: the regime's short flights (:data:`~quadwind_trl.quick.PPO_QUICK`),
    8 envs, 4 tiny iterations."""
    quick = PPO_QUICK[regime]
    spec = replace(spec, config=quick.config(spec.env_config), ranges=quick.ranges(DEFAULT_RANGES[regime]), num_envs=8,
                   compile_step=False)
    cfg = PPOConfig(total_frames=4 * 8 * 32, num_envs=8, steps_per_env=32, epochs=2, minibatch=128,
                    eval_every_frames=0, checkpoint_every_frames=2 * 8 * 32)
    changes = [
        f"flights: {quick.describe()}",
        "PPO: 8 envs x 32 steps, 4 iterations, 2 epochs, minibatch 128; evaluation: 1 episode from the pattern start",
        "simulator eager (compiling would cost more than the whole run)",
    ]
    return spec, cfg, changes


def with_residual_on(config: EnvConfig, target: str) -> EnvConfig:
    """``config`` with its residual acting on ``target`` (``ResidualConfig.acts_on``)."""
    return replace(config, residual=replace(config.residual, acts_on=target))


def with_reward_w_z(config: EnvConfig, w_z: float | None) -> EnvConfig:
    """``config`` with the reward's height weight ``w_z`` (None: unchanged, the regime's preset)."""
    return config if w_z is None else replace(config, reward=replace(config.reward, w_z=w_z))


def recipe_ppo_config(regime: str, args: argparse.Namespace, base: PPOConfig | None = None) -> PPOConfig:
    """The run's PPO settings: ``base`` (the ``--quick`` ones) or the recipe's defaults, with the
    options given in ``args``; checked (``PPOConfig.validate``)."""
    cfg = base or PPOConfig(eval_every_frames=DEFAULT_EVAL_EVERY[regime], background_eval=DEFAULT_BACKGROUND_EVAL)
    overrides = {"seed": args.seed, "threads": args.threads}
    for arg, name in (("total_frames", "total_frames"), ("num_envs", "num_envs"), ("steps_per_env", "steps_per_env"),
                      ("eval_every", "eval_every_frames"), ("lr_schedule", "lr_schedule"),
                      ("reward_scaling", "reward_scaling"), ("value_norm", "value_norm"), ("init_scale", "init_scale"),
                      ("collect_workers", "collect_workers"),
                      ("collector", "collector"), ("num_collectors", "num_collectors"), ("address", "ray_address"),
                      ("background_eval", "background_eval")):
        if getattr(args, arg) is not None:
            overrides[name] = getattr(args, arg)
    return replace(cfg, **overrides).validate()


def run(regime: str, args: argparse.Namespace, *, curriculum: bool = False) -> dict:
    """Build the env spec, PPO config, evaluation set and (vertical) curriculum from ``args``;
    train; print and return the final manifest."""
    torch.set_num_threads(args.threads)
    try:
        config, base_wind = with_base_controller(
            regime, with_reward_w_z(with_sensing(regime_config(regime), args.sensing), args.reward_w_z), args.base_controller)
        config = with_residual_on(config, args.residual_on).validate()
        spec = RLEnvSpec(regime=regime, wind_input=args.wind_input, device=args.device, seed=args.seed,
                         estimator_path=args.estimator, untrained_estimator=args.untrained_estimator,
                         config=config, base_wind_input=base_wind, compile_step=not args.eager,
                         zero_inputs=input_channels(args.zero_inputs), base_state_inputs=tuple(args.base_state_inputs),
                         preview_inputs=tuple(args.preview_inputs),
                         privileged_inputs=tuple(args.privileged_inputs), memory_frames=args.memory_frames,
                         recurrent_hidden=args.recurrent_hidden)
    except ValueError as err:  # a bad setting (e.g. --zero-inputs tilt): the message names the allowed values
        raise SystemExit(f"error: {err}") from None
    quick_cfg = None
    if args.quick:
        spec, quick_cfg, changes = quick_setup(regime, spec)
        print("--quick changes from the full run:")
        for line in changes:
            print(f"  {line}")
    try:
        cfg = recipe_ppo_config(regime, args, quick_cfg)
        check_device(cfg, spec.device)
        check_recurrent(cfg, spec)
    except ValueError as err:  # e.g. --collect-workers 3 with 64 envs: the message names the field and the rule
        raise SystemExit(f"error: {err}") from None
    try:  # a missing Ray, or an --address where no head node answers, before anything is built
        check_ray(cfg)
    except RayUnavailable as err:
        raise SystemExit(f"error: {err}") from None
    spec = replace(spec, num_envs=cfg.num_envs)

    # fail early on a missing estimator, with the message naming the options
    bundle = None
    if spec.wind_input != "truth" or spec.estimator_path is not None:
        try:
            bundle = load_estimator(regime, spec.estimator_path, untrained=spec.untrained_estimator,
                                    config=spec.env_config, device=spec.device)
        except (FileNotFoundError, ValueError) as err:
            raise SystemExit(f"error: {err}") from None
    tau_s = args.ema_tau_s if args.ema_tau_s is not None else validated_tau_s(bundle)
    every_s = (args.estimate_every_s if args.estimate_every_s is not None
               else recipe_estimate_every_s(tau_s, spec.env_config.timing.log_dt_s))
    try:
        spec = replace(spec, ema_tau_s=tau_s, estimate_every_s=every_s)
    except ValueError as err:  # e.g. --estimate-every-s 0.25: the message names the allowed values
        raise SystemExit(f"error: {err}") from None
    print(f"wind estimate EMA: tau = {spec.ema_tau_s:g} s; estimator every {spec.estimate_every_s:g} s; "
          f"wind input: {spec.wind_input}; inputs zeroed: {', '.join(spec.zero_inputs) or 'none'}; base state read: "
          f"{', '.join(spec.base_state_inputs) or 'none'}; reference ahead read: "
          f"{', '.join(spec.preview_inputs) or 'none'}; critic's privileged inputs: "
          f"{', '.join(spec.privileged_inputs) or 'none'}; memory: {spec.memory_frames} frame(s)"
          f"; residual on the {spec.env_config.residual.acts_on}"
          f"{f', recurrent actor of {spec.recurrent_hidden} units' if spec.recurrent_hidden else ''}", flush=True)

    episodes = args.eval_episodes if args.eval_episodes is not None else (1 if args.quick else None)
    scenarios = validation_scenarios(regime, episodes) if episodes != 0 else None
    if args.quick and scenarios is not None:
        scenarios = PPO_QUICK[regime].scenarios(scenarios, DEFAULT_RANGES[regime].top_altitude_m)
    out = Path(args.out or f"runs/ppo_{regime}{'_quick' if args.quick else ''}")
    trainer = PPOTrainer(
        spec, cfg, out,
        eval_scenarios=scenarios,
        curriculum=vertical_curriculum(spec.trajectories) if curriculum else None,
        logger=args.logger,
        progress=not args.no_progress,
        estimator_bundle=bundle,
    )  # fmt: skip
    t0 = time.perf_counter()
    try:
        result = trainer.train(resume=args.resume)
    except (FileExistsError, FileNotFoundError, ResumeMismatch, RayUnavailable) as err:  # --resume mistakes, no Ray cluster
        raise SystemExit(f"error: {err}") from None
    manifest = json.loads((out / "policy.json").read_text())
    m = manifest["metrics"]
    print(f"done: {result.frames} frames, {result.iterations} iterations, {time.perf_counter() - t0:.0f} s this session "
          f"({result.wall_time_s:.0f} s in total) -> {out / 'policy.pt'}")
    if m:
        print(f"kept policy (evaluated at {m['frames']:,} frames, {manifest['selection']['evaluations']} evaluations): "
              f"rmse {m['rmse']:.3f} m vs the base law alone {m['pd_rmse']:.3f} m "
              f"(RMSE reduction {m['improvement_vs_pd']:+.1f} %; xy {m['improvement_rmse_xy_pct']:+.1f} %, "
              f"z {m['improvement_rmse_z_pct']:+.1f} %; positive = better than the base law), "
              f"win rate {m['win_rate']:.2f}, crashed {m['crashed']}")
    return manifest
