"""Screening the learning levers: for named lever settings x seeds, train the residual on a
classical base, fly the kept policy on the regime's validation sweep paired with the base alone
(episode by episode), and keep one row per run on disk, so that a screen resumes where it stopped.

A lever setting is a name and the PPO recipes' flags it adds (:data:`LEVERS`, or ``NAME=FLAGS``
on the command line): the runs train exactly as ``recipes/ppo_horizontal.py`` (or the vertical
curriculum) would with those flags (:func:`quadwind_trl.rl.cli.run`). Choices are made here, on
validation flights; the test sweeps are never flown.

    rows = screen(plan)               # trains and evaluates what has no row yet
    write_table(rows, "screen.md")    # lever, seeds, validation xy / z gain over the base, cost
"""
from __future__ import annotations

import json
import shlex
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Sequence

import torch

from ..estimator import load_estimator
from ..manifest import git_commit, repo_relative, write_json
from ..quick import PPO_QUICK
from ..regimes import CLASSICAL_CONTROLLERS
from .cli import build_parser, run
from .envs import DEFAULT_RANGES, check_regime, make_env, policy_env_settings
from .paired import fly_paired, validation_scenarios
from .policy import load_policy

# the estimators with the lowest error per window the project has measured (trailing-mean inputs;
# results/experiments/estimator/, docs/estimator.md), per regime
TRAILING_ESTIMATOR = {"horizontal": "results/experiments/estimator/trailing_10_30_120_300.pt",
                      "vertical": "results/experiments/estimator/vertical_trailing_10_30_120_300.pt"}


def _levers(regime: str) -> dict[str, tuple[str, ...]]:
    return {
        "residual": (),  # the residual as the recipes train it: the reference row
        "base_state": ("--base-state-inputs", "all"),  # every channel of the base law's state
        "privileged_critic": ("--privileged-inputs", "mean_wind", "turbulence", "true_error", "true_vel_error"),
        "memory4": ("--memory-frames", "4"),
        "recurrent64": ("--recurrent-hidden", "64"),  # a GRU of 64 units before the actor's MLP
        "combined": ("--base-state-inputs", "all", "--privileged-inputs", "mean_wind", "turbulence",
                     "true_error", "true_vel_error", "--memory-frames", "4"),
        "ema_tau_3": ("--ema-tau-s", "3"),  # the paper's wind filter instead of the validated one
        # its checkpoint records no validated tau, so it trains behind the paper's 3 s as well:
        # against ema_tau_3 it is the estimator alone that differs
        "trailing_estimator": ("--estimator", TRAILING_ESTIMATOR[regime]),
        # the critic's targets on a steadier scale: rewards divided by the running std of the return
        "return_scaling": ("--reward-scaling", "return_std"),
        "longer_rollouts": ("--steps-per-env", "512"),  # twice the decisions per row and batch
        # the critic's targets standardised by their running mean / std (PopArt-style, rl/value_norm.py)
        "value_norm": ("--value-norm",),
        # the residual reads the true mean wind instead of the estimate: the privileged upper bound
        # of what wind information adds (the base law is unchanged)
        "oracle_wind": ("--wind-input", "truth"),
        # the residual corrects the base law's desired acceleration (where the observer corrects),
        # not its wrench: the policy need not learn the attitude loop
        "accel_residual": ("--residual-on", "acceleration"),
        # the residual reads where the reference will be 0.5, 1 and 2 s from now: it can start a turn
        # or a climb before the error shows, where the commanded-tilt limit leaves a reactive law behind
        "preview": ("--preview-inputs", "ahead_0.5s", "ahead_1s", "ahead_2s"),
    }


#: the named lever settings of a screen (flags of the PPO recipes), per regime
LEVERS: dict[str, dict[str, tuple[str, ...]]] = {regime: _levers(regime) for regime in ("horizontal", "vertical")}


def parse_lever(text: str, regime: str) -> tuple[str, tuple[str, ...]]:
    """``(name, flags)`` of a lever setting: a name of :data:`LEVERS` or ``NAME=FLAGS`` (the PPO
    recipes' flags, shell-quoted, e.g. ``"mem8=--memory-frames 8"``)."""
    check_regime(regime)
    name, eq, flags = text.partition("=")
    if eq:
        if not name.isidentifier():
            raise ValueError(f"lever {text!r}: NAME=FLAGS needs a NAME of letters, digits and _; got {name!r}")
        return name, tuple(shlex.split(flags))
    if text not in LEVERS[regime]:
        raise ValueError(f"lever {text!r}; allowed: {sorted(LEVERS[regime])} or NAME=FLAGS (PPO recipe flags)")
    return text, LEVERS[regime][text]


@dataclass(frozen=True)
class ScreenPlan:
    """What a screen trains and where it writes."""

    regime: str = "horizontal"
    base: str = "dob"  # the classical base the residual is added to (regimes.CLASSICAL_CONTROLLERS)
    levers: tuple[tuple[str, tuple[str, ...]], ...] = (("residual", ()),)  # (name, flags) of each setting
    seeds: tuple[int, ...] = (0, 1, 2)
    frames: int = 500_000  # decisions each run trains for
    out: Path = Path("results/experiments/levers")  # rows/, screen.json, screen.md
    runs: Path = Path("runs/screen_levers")  # the training runs (checkpoints, logs: never committed)
    val_episodes: int | None = None  # the validation sweep's episodes each run is scored on (None: all)
    extra_flags: tuple[str, ...] = ()  # flags every run adds (e.g. --threads 1, --untrained-estimator)
    quick: bool = False  # the recipes' --quick runs (smoke tests), scored on their short flights
    resamples: int = 10_000  # bootstrap resamples of each paired interval

    def __post_init__(self):
        check_regime(self.regime)
        if self.base not in CLASSICAL_CONTROLLERS:
            raise ValueError(f"ScreenPlan.base={self.base!r}; allowed: {CLASSICAL_CONTROLLERS}")
        if not self.levers or not self.seeds:
            raise ValueError(f"ScreenPlan: levers={self.levers!r}, seeds={self.seeds!r}; allowed: at least one of each")
        names = [name for name, _ in self.levers]
        if len(set(names)) < len(names):
            raise ValueError(f"ScreenPlan.levers: the names {names} repeat; allowed: each name once")
        if self.frames < 1:
            raise ValueError(f"ScreenPlan.frames={self.frames}; allowed: >= 1")
        if self.val_episodes is not None:  # refused now, not after the first run has trained
            n = validation_scenarios(self.regime).batch_size[0]
            if not 1 <= self.val_episodes <= n:
                raise ValueError(f"ScreenPlan.val_episodes={self.val_episodes}; allowed: 1 to {n} (the {self.regime} "
                                 "validation sweep), or None for all of it")

    def row_path(self, lever: str, seed: int) -> Path:
        return self.out / "rows" / f"{lever}_seed{seed}.json"

    def run_dir(self, lever: str, seed: int) -> Path:
        return self.runs / f"{self.regime}_{self.base}" / lever / f"seed{seed}"

    def recipe_args(self, lever: str, flags: Sequence[str], seed: int) -> list[str]:
        """The PPO recipe's command-line arguments of one run (``--resume``: an interrupted run
        continues from its checkpoint, a finished one only writes its policy again)."""
        return [*flags, *self.extra_flags, "--base-controller", self.base, "--seed", str(seed), "--total-frames",
                str(self.frames), "--resume", "--no-progress", *(["--quick"] if self.quick else []),
                "--out", str(self.run_dir(lever, seed))]


def _gain(base: torch.Tensor, policy: torch.Tensor, resamples: int) -> dict:
    """The policy's RMSE reduction over the base in %, with its paired bootstrap 95 % interval and
    wins; and, because that reduction is of the mean RMSE, which one episode can decide, the median
    of the per-episode reductions and the episode the policy loses most on (its index in the
    validation episodes scored, and both RMSEs)."""
    from ..evaluation.statistics import paired_summary

    s = paired_summary(base, policy, resamples=resamples)
    worst = int(torch.argmax(policy - base))
    return {"gain_pct": s["improvement"], "ci_low_pct": s["ci_low"], "ci_high_pct": s["ci_high"], "wins": s["wins"],
            "episodes": s["n"], "base_mean_m": s["baseline_mean"], "policy_mean_m": s["other_mean"],
            "median_episode_gain_pct": float(100.0 * (1.0 - policy.double() / base.double()).median()),
            "worst_episode": {"index": worst, "base_m": float(base[worst]), "policy_m": float(policy[worst])}}


def score_on_validation(policy_path: str | Path, plan: ScreenPlan) -> dict:
    """The kept policy and the base alone (the zero residual, in the policy's own env) flown on the
    regime's validation sweep, the same episodes: xy and z gain with intervals, crashes, seconds."""
    actor, payload = load_policy(policy_path)
    from ..evaluation.ablation import policy_compile_step, policy_env_config

    spec = payload["env_spec"]
    estimator = None
    if spec["wind_input"] != "truth" or spec.get("estimator_path") is not None:
        estimator = load_estimator(plan.regime, spec.get("estimator_path"), untrained=spec.get("untrained_estimator", False),
                                   config=policy_env_config(payload))
    scenarios = validation_scenarios(plan.regime, plan.val_episodes)
    if plan.quick:
        scenarios = PPO_QUICK[plan.regime].scenarios(scenarios, DEFAULT_RANGES[plan.regime].top_altitude_m)
    env = make_env(plan.regime, estimator, scenarios.batch_size[0], wind_input=spec["wind_input"],
                   config=policy_env_config(payload), vecnorm_state=payload["vecnorm"],
                   compile_step=policy_compile_step(payload), **policy_env_settings(spec, estimator))
    t0 = time.perf_counter()
    flown = fly_paired({"base": (env, None), "policy": (env, actor)}, scenarios)
    base, policy = flown["base"], flown["policy"]
    return {"xy": _gain(base.rmse_xy, policy.rmse_xy, plan.resamples), "z": _gain(base.rmse_z, policy.rmse_z, plan.resamples),
            "crashed": {"base": int(base.crashed.sum()), "policy": int(policy.crashed.sum())},
            "eval_s": round(time.perf_counter() - t0, 1)}


@dataclass
class ScreenRow:
    """One run of a screen: a lever setting, a seed, and its validation score against the base."""

    lever: str
    flags: list[str]
    seed: int
    regime: str
    base: str
    frames: int
    validation: dict
    train_wall_s: float
    wall_s: float  # training (all sessions) + scoring
    policy: str
    git_commit: str | None
    extra_flags: list[str] = field(default_factory=list)
    val_episodes: int | None = None  # the validation episodes scored (None: the whole sweep)
    recipe_args: list[str] = field(default_factory=list)


class ScreenMismatch(ValueError):
    """A row on disk was written for another run than the one a screen asks under its name."""


def _finished(path: Path, flags: Sequence[str], plan: ScreenPlan) -> ScreenRow | None:
    """The row on disk for this run, if one was written for the same run (flags, frames, regime,
    base, flags given to every run, validation episodes); a :class:`ScreenMismatch` if it was
    written for another."""
    if not path.exists():
        return None
    row = ScreenRow(**json.loads(path.read_text()))
    saved = (row.regime, row.base, list(row.flags), list(row.extra_flags), row.frames, row.val_episodes)
    asked = (plan.regime, plan.base, list(flags), list(plan.extra_flags), plan.frames, plan.val_episodes)
    if saved != asked:
        raise ScreenMismatch(f"{path} holds a run of (regime, base, flags, flags of every run, frames, validation "
                             f"episodes) = {saved}; this screen asks {asked} under that name: give the setting another "
                             "name, or another --out")
    return row


def screen(plan: ScreenPlan, log=print) -> list[ScreenRow]:
    """Every (lever setting, seed) of ``plan``: its row from disk when finished, else trained (from
    its checkpoint when one is there) and scored; one JSON row per run written as it finishes.
    Rows on disk that another run wrote under a name of ``plan`` are refused before anything trains."""
    for name, flags in plan.levers:
        for seed in plan.seeds:
            _finished(plan.row_path(name, seed), flags, plan)
    rows = []
    for name, flags in plan.levers:
        for seed in plan.seeds:
            path = plan.row_path(name, seed)
            done = _finished(path, flags, plan)
            if done is not None:
                log(f"[{name} seed {seed}] finished earlier: {repo_relative(path)}")
                rows.append(done)
                continue
            argv = plan.recipe_args(name, flags, seed)
            log(f"[{name} seed {seed}] training: {' '.join(shlex.quote(a) for a in argv)}")
            parser = build_parser(plan.regime, "screen run")
            # the code this run imports and trains: taken now, since the tree may be committed to
            # (or edited) while a run of many minutes trains, and the row must name what flew
            commit = git_commit()
            manifest = run(plan.regime, parser.parse_args(argv), curriculum=plan.regime == "vertical")
            policy = plan.run_dir(name, seed) / "policy.pt"
            validation = score_on_validation(policy, plan)
            row = ScreenRow(lever=name, flags=list(flags), seed=seed, regime=plan.regime, base=plan.base,
                            frames=manifest["frames"], validation=validation, train_wall_s=manifest["wall_time_s"],
                            wall_s=round(manifest["wall_time_s"] + validation["eval_s"], 1), policy=repo_relative(policy),
                            git_commit=commit, extra_flags=list(plan.extra_flags), val_episodes=plan.val_episodes,
                            recipe_args=argv)
            write_json(path, asdict(row))
            log(f"[{name} seed {seed}] validation xy {validation['xy']['gain_pct']:+.1f} % "
                f"[{validation['xy']['ci_low_pct']:+.1f}, {validation['xy']['ci_high_pct']:+.1f}], z "
                f"{validation['z']['gain_pct']:+.1f} % over {plan.base} alone -> {repo_relative(path)}")
            rows.append(row)
    return rows


def collect(folders: Sequence[Path]) -> tuple[list[ScreenRow], list[str]]:
    """The rows (``rows/*.json``) and commands (``screen.json``) of several screens' output
    folders, as one screen: seeds or levers run beside each other, each screen in a folder of its
    own (a folder is held by one screen at a time). Refused: folders of other regimes, bases,
    frames or validation episodes, and a (lever, seed) found in two folders."""
    rows: dict[tuple[str, int], tuple[ScreenRow, Path]] = {}
    commands = []
    for folder in folders:
        paths = sorted(Path(folder).glob("rows/*.json"))
        if not paths:
            raise ValueError(f"collect: {folder} holds no rows (rows/*.json)")
        if (Path(folder) / "screen.json").exists():
            commands.append(json.loads((Path(folder) / "screen.json").read_text())["command"])
        for path in paths:
            row = ScreenRow(**json.loads(path.read_text()))
            if (row.lever, row.seed) in rows:
                raise ValueError(f"collect: {row.lever} seed {row.seed} is in {rows[row.lever, row.seed][1]} and {path}")
            rows[row.lever, row.seed] = (row, path)
    found = {(r.regime, r.base, r.frames, r.val_episodes) for r, _ in rows.values()}
    if len(found) > 1:
        raise ValueError(f"collect: the folders hold screens of other (regime, base, frames, validation episodes): "
                         f"{sorted(found, key=str)}; one screen is one of each")
    return [r for r, _ in rows.values()], commands


def summarize(rows: Sequence[ScreenRow]) -> list[dict]:
    """Per lever setting, in the order first seen: seeds, mean / min / max of the xy and z gains,
    the seeds whose xy interval lies above zero, and the mean wall time per run."""
    out = []
    for name in dict.fromkeys(r.lever for r in rows):
        mine = [r for r in rows if r.lever == name]
        entry = {"lever": name, "flags": mine[0].flags, "seeds": [r.seed for r in mine]}
        for axis in ("xy", "z"):
            gains = [r.validation[axis]["gain_pct"] for r in mine]
            entry[axis] = {"mean_pct": sum(gains) / len(gains), "min_pct": min(gains), "max_pct": max(gains),
                           "seeds_above_zero": sum(r.validation[axis]["ci_low_pct"] > 0 for r in mine)}
        entry["wall_s_mean"] = sum(r.wall_s for r in mine) / len(mine)
        entry["frames"] = sorted({r.frames for r in mine})
        out.append(entry)
    return out


def table(rows: Sequence[ScreenRow], base: str) -> str:
    """The screen as markdown: one line per lever setting (validation gain over ``base`` alone,
    mean and range over seeds), then one per run with its paired interval."""
    lines = [f"| lever | flags | seeds | validation xy gain over {base}: mean [min, max] | xy interval > 0 | "
             f"z gain: mean [min, max] | frames | wall per run |", "|---|---|---|---|---|---|---|---|"]
    for s in summarize(rows):
        xy, z = s["xy"], s["z"]
        lines.append(f"| {s['lever']} | `{' '.join(s['flags']) or '-'}` | {len(s['seeds'])} | {xy['mean_pct']:+.1f} % "
                     f"[{xy['min_pct']:+.1f}, {xy['max_pct']:+.1f}] | {xy['seeds_above_zero']}/{len(s['seeds'])} | "
                     f"{z['mean_pct']:+.1f} % [{z['min_pct']:+.1f}, {z['max_pct']:+.1f}] | "
                     f"{', '.join(f'{f:,}' for f in s['frames'])} | {s['wall_s_mean'] / 60:.1f} min |")
    lines += ["", "| lever | seed | xy gain (95 % interval) | xy wins | z gain (95 % interval) | crashed (base / policy) | "
                  "wall | xy median episode gain | xy worst loss: episode, base -> policy |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        xy, z, c = r.validation["xy"], r.validation["z"], r.validation["crashed"]
        lines.append(f"| {r.lever} | {r.seed} | {xy['gain_pct']:+.1f} % [{xy['ci_low_pct']:+.1f}, {xy['ci_high_pct']:+.1f}] "
                     f"| {xy['wins']}/{xy['episodes']} | {z['gain_pct']:+.1f} % [{z['ci_low_pct']:+.1f}, "
                     f"{z['ci_high_pct']:+.1f}] | {c['base']} / {c['policy']} | {r.wall_s / 60:.1f} min | {_tail(xy)} |")
    return "\n".join(lines) + "\n"


def _tail(gain: dict) -> str:
    """The median episode's gain and the worst loss, as table cells ("-" for rows written before
    screens recorded them)."""
    if "worst_episode" not in gain:
        return "- | -"
    w = gain["worst_episode"]
    return f"{gain['median_episode_gain_pct']:+.1f} % | {w['index']}: {w['base_m']:.3f} -> {w['policy_m']:.3f} m"
