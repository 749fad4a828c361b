"""How often the wind estimator needs to run: its cost, and what querying it every 0.5 s or 1 s
instead of at every 0.1 s log tick changes (``RLEnvSpec.estimate_every_s``).

    python bench/estimator_tick.py                    # N = 64, k = 1 5 10, quick horizontal subset
    python bench/estimator_tick.py --pattern-s 30     # the same worlds on 30 s patterns
    python bench/estimator_tick.py --skip-effect --compile   # (a) on the compiled step, as training

(a) Cost, per k (queries every k log ticks): the horizontal training env (``make_env``: ground
starts, first-episode de-synchronisation, the full transform stack, the eager simulator step or
with ``--compile`` the compiled one, as training flies it, the shipped estimator) with N rows, collected by TorchRL's ``Collector`` with the TanhNormal actor in
RANDOM mode: one warm-up batch, then ``--batches`` timed batches of N x ``--steps`` frames.
``estimator_net_ms`` is the network per env step, ``estimator_all_ms`` the whole ``WindEstimate``
tick (features + ring, still every tick, + network + EMA), ``frames_per_s`` the collection rate.

(b), (c) Effect: the shipped horizontal policy flown wind-aware, and PD, on the horizontal
sweep's ``--quick`` subset (``evaluation.tracking.sweep_setup``; ``--pattern-s`` lengthens its
patterns), through ``evaluation.ablation.fly_controllers`` as ``recipes/ablation.py`` flies it,
with every k (PD does not read the estimate: flown once). (b) how far ``wind_hat`` moves against
k = 1 over all steps after the first 6 s: RMS and max of the (north, east) difference, m/s, and
that RMS relative to the RMS error of the k = 1 estimate against the true mean wind on the same
steps; (c) the ablation's figures: the paired xy RMSE reduction vs PD and the mean xy RMSE.

Prints ``machine ...``, then one parseable line per k and part::

    estimator_tick_cost N=64 every_s=... estimator_calls_per_step=... estimator_net_ms=... ...
    estimator_tick_wind every_s=... episodes=... rms_diff_m_s=... max_diff_m_s=... rel_to_wind_error=...
    estimator_tick_ablation every_s=... episodes=... xy_improvement_pct=... mean_rmse_xy_m=... ...
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import torch
from machine import load_1min, machine_line

from quadwind_trl.estimator import load_estimator
from quadwind_trl.evaluation.ablation import fly_controllers, policy_env_config
from quadwind_trl.evaluation.tracking import sweep_setup
from quadwind_trl.keys import MEAN_WIND_KEY, WIND_KEY
from quadwind_trl.manifest import CHECKPOINT_DIR
from quadwind_trl.quick import SWEEP_QUICK
from quadwind_trl.regimes import SWEEPS
from quadwind_trl.rl.envs import RLEnvSpec, make_env, wind_estimate
from quadwind_trl.rl.paired import improvement
from quadwind_trl.rl.policy import load_policy

LOG_DT_S = 0.1  # the 10 Hz flight record
SETTLE_S = 6.0  # the estimator's window (60 samples) is full from here on


def cost(n: int, every_s: float, steps: int, batches: int, bundle, compile_step: bool) -> dict:
    """(a): one k's estimator time per env step and collection frames/s at ``n`` rows."""
    from torchrl.collectors import Collector
    from torchrl.envs.utils import ExplorationType

    from quadwind_trl.rl.config import PPOConfig
    from quadwind_trl.rl.policy import build_actor_critic
    from quadwind_trl.rl.trainer import episode_steps_hint

    torch.manual_seed(0)
    env = make_env("horizontal", bundle, n, desync_steps=episode_steps_hint(RLEnvSpec("horizontal")),
                   compile_step=compile_step, estimate_every_s=every_s)
    west = wind_estimate(env)
    tick_s = [0.0]
    raw_tick = west._tick

    def timed_tick(record, mask):  # the whole tick: features, ring, network, EMA
        t0 = time.perf_counter()
        raw_tick(record, mask)
        tick_s[0] += time.perf_counter() - t0

    west._tick = timed_tick
    actor, _ = build_actor_critic(PPOConfig())
    collector = Collector(env, actor, frames_per_batch=n * steps, total_frames=n * steps * (batches + 1),
                          exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
    it = iter(collector)
    next(it)  # warm-up (and the compilation, once per process)
    tick_s[0], west.estimator_seconds, west.estimator_calls = 0.0, 0.0, 0
    t0 = time.perf_counter()
    for _ in range(batches):
        next(it)
    collect_s = time.perf_counter() - t0
    collector.shutdown()
    env_steps = steps * batches
    return {
        "N": n,
        "every_s": every_s,
        "compile": compile_step,
        "env_steps": env_steps,
        "estimator_calls_per_step": round(west.estimator_calls / env_steps, 2),
        "estimator_net_ms": round(1e3 * west.estimator_seconds / env_steps, 2),
        "estimator_all_ms": round(1e3 * tick_s[0] / env_steps, 2),
        "collect_ms": round(1e3 * collect_s / env_steps, 2),
        "share_estimator_net": round(west.estimator_seconds / collect_s, 3),
        "frames_per_s": round(n * env_steps / collect_s),
        "load_1min": round(load_1min(), 2),
    }


def mean_wind_ne(log) -> torch.Tensor:
    """The true turbulence-free mean wind, (north, east) as ``wind_hat`` orders it (ENU stored)."""
    mean = log.get(MEAN_WIND_KEY)
    return torch.stack((mean[..., 1], mean[..., 0]), -1)


def wind_movement(reference, other) -> dict:
    """(b): ``wind_hat`` of ``other`` against ``reference`` (k = 1) on the steps both flew after
    the first ``SETTLE_S`` seconds."""
    ref, log = reference.log, other.log
    t = min(ref.batch_size[1], log.batch_size[1])
    ref, log = ref[:, :t], log[:, :t]
    scored = ref["valid"] & log["valid"]
    scored[:, : round(SETTLE_S / LOG_DT_S)] = False
    diff = (log[WIND_KEY] - ref[WIND_KEY]).norm(dim=-1)[scored]
    error = (ref[WIND_KEY] - mean_wind_ne(ref)).norm(dim=-1)[scored]
    rms = diff.square().mean().sqrt().item()
    return {
        "samples": int(scored.sum()),
        "rms_diff_m_s": round(rms, 4),
        "max_diff_m_s": round(diff.max().item(), 4),
        "rms_wind_error_k1_m_s": round(error.square().mean().sqrt().item(), 3),
        "rel_to_wind_error": round(rms / error.square().mean().sqrt().item(), 4),
    }


def ablation_figures(pd, aware, reference) -> dict:
    """(c): the paired xy RMSE reduction vs PD, the mean xy RMSE, and the largest per-episode
    change against k = 1."""
    return {
        "xy_improvement_pct": round(improvement(pd.rmse_xy, aware.rmse_xy), 2),
        "mean_rmse_xy_m": round(aware.rmse_xy.double().mean().item(), 4),
        "wins": int((aware.rmse_xy < pd.rmse_xy).sum()),
        "max_episode_change_m": round((aware.rmse_xy - reference.rmse_xy).abs().max().item(), 4),
        "crashed": int(aware.crashed.sum()),
    }


def effect(every: list[float], pattern_s: float | None) -> None:
    """(b) and (c) for each k, printed as they are flown."""
    policy = CHECKPOINT_DIR / "policy_horizontal.pt"
    estimator = load_estimator("horizontal", config=policy_env_config(load_policy(policy)[1]))
    scenarios, override = sweep_setup(SWEEPS["horizontal"], quick=True)
    if pattern_s is not None:
        override = replace(SWEEP_QUICK, pattern_s=pattern_s).config
    pd = reference = None
    for every_s in every:
        t0 = time.perf_counter()
        controllers = ("pd", "aware") if pd is None else ("aware",)  # PD never reads the estimate
        results = fly_controllers("horizontal", scenarios, policy, estimator, controllers, config_override=override,
                                  compile_step=False, log_keys=(MEAN_WIND_KEY, WIND_KEY), estimate_every_s=every_s)
        pd = results.get("pd", pd)
        aware = results["aware"]
        reference = aware if reference is None else reference
        common = {"every_s": every_s, "episodes": scenarios.batch_size[0],
                  "pattern_s": pattern_s or SWEEP_QUICK.pattern_s}
        tail = {"flight_s": round(time.perf_counter() - t0, 1), "load_1min": round(load_1min(), 2)}
        wind = common | wind_movement(reference, aware) | tail
        print("estimator_tick_wind " + " ".join(f"{k}={v}" for k, v in wind.items()), flush=True)
        figures = common | ablation_figures(pd, aware, reference) | tail
        print("estimator_tick_ablation " + " ".join(f"{k}={v}" for k, v in figures.items()), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--every-s", type=float, nargs="+", default=[0.1, 0.5, 1.0],
                        help="seconds between estimator queries; the first is the reference (default 0.1 0.5 1.0)")
    parser.add_argument("--num-envs", type=int, default=64, help="rows of the cost measurement (training: 64)")
    parser.add_argument("--steps", type=int, default=30, help="env steps per row per collected batch")
    parser.add_argument("--batches", type=int, default=2, help="timed batches per k")
    parser.add_argument("--pattern-s", type=float, default=None,
                        help=f"pattern length of (b), (c) (default: the quick subset's {SWEEP_QUICK.pattern_s:g} s)")
    parser.add_argument("--skip-cost", action="store_true", help="only (b) and (c)")
    parser.add_argument("--skip-effect", action="store_true", help="only (a)")
    parser.add_argument("--compile", action="store_true", help="(a) on the compiled simulator step (default: eager)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(machine_line(args.threads), flush=True)
    if not args.skip_cost:
        bundle = load_estimator("horizontal")
        for every_s in args.every_s:
            r = cost(args.num_envs, every_s, args.steps, args.batches, bundle, args.compile)
            print("estimator_tick_cost " + " ".join(f"{k}={v}" for k, v in r.items()), flush=True)
    if not args.skip_effect:
        effect(args.every_s, args.pattern_s)


if __name__ == "__main__":
    main()
