"""Train Stable-Baselines3's PPO (the paper's trainer) on the gymnasium adapter.

    pip install -e '.[sb3]'
    python recipes/sb3_ppo.py                          # 4,096 decisions on short flights (minutes)
    python recipes/sb3_ppo.py --total-timesteps 3000000 --full-flights --out runs/sb3_horizontal

The env is ``gym.make("QuadWind-Horizontal-v0")`` (or ``-Vertical-``): the same simulator,
estimator transform, observation and action as the TorchRL recipes (``quadwind_trl/gym.py``),
its normalisation frozen at the shipped policy's statistics. SB3's defaults are the paper's PPO
settings except ``n_steps``, which is smaller here so a short run makes several updates.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import torch

from quadwind_trl.gym import ENV_IDS  # importing the module registers the env ids
from quadwind_trl.outputs import hold_for_command
from quadwind_trl.quick import QuickFlights
from quadwind_trl.regimes import regime_config


QUICK = QuickFlights(pattern_s=10.0, vertical_top_m=15.0, vertical_hold_s=1.0)  # flights of seconds


def short_flights(regime: str) -> dict:
    """make_env keywords for :data:`QUICK` flights, started at the pattern, simulator eager (a smoke
    run: compiling the step would cost more than flying it)."""
    return {"config": QUICK.config(regime_config(regime)), "start": "pattern", "compile_step": False}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regime", default="horizontal", choices=list(ENV_IDS))
    parser.add_argument("--total-timesteps", type=int, default=4096, help="policy decisions (0.1 s of flight each)")
    parser.add_argument("--n-steps", type=int, default=512, help="decisions per PPO update (paper: 2048 per env)")
    parser.add_argument("--full-flights", action="store_true", help="the regime's full-length flights from the ground")
    parser.add_argument("--out", type=Path, default=Path("runs/sb3_ppo"), help="where the SB3 model is saved")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    hold_for_command(args.out, what="SB3 run", hint="wait for it to finish, or choose another --out")
    try:
        from stable_baselines3 import PPO
    except ImportError:
        raise SystemExit("error: stable-baselines3 is not installed; pip install -e '.[sb3]'") from None
    torch.set_num_threads(1)
    env = gym.make(ENV_IDS[args.regime], **({} if args.full_flights else short_flights(args.regime)))
    batch = min(64, args.n_steps)
    model = PPO("MlpPolicy", env, n_steps=args.n_steps, batch_size=batch, seed=args.seed, verbose=0,
                policy_kwargs={"net_arch": [256, 256]})
    t0 = time.perf_counter()
    model.learn(total_timesteps=args.total_timesteps, progress_bar=False)
    args.out.mkdir(parents=True, exist_ok=True)
    model.save(args.out / "model.zip")
    rewards = [ep["r"] for ep in model.ep_info_buffer] if model.ep_info_buffer else []
    mean = f"{sum(rewards) / len(rewards):.1f}" if rewards else "n/a"
    print(f"SB3 PPO: {model.num_timesteps} decisions in {time.perf_counter() - t0:.0f} s, "
          f"mean episode return {mean} over the last {len(rewards)} episodes -> {args.out / 'model.zip'}")


if __name__ == "__main__":
    main()
