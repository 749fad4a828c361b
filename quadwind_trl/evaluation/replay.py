"""Exact replay: records of per-episode RMSEs of a sweep slice as ``float.hex`` strings, the
check of an ablation results file against its re-flown batches (:func:`verify_ablation`), and the
contract between a record and a re-flight (:func:`replay_verdict`; docs/simulator.md, "Exact
replay").

A record pins PD on the default vehicle and the shipped policy (wind-blind and wind-aware) of the
sweep's regime on the same episodes, flown in one batch of the slice's size, and the platform it
was made on (:func:`~quadwind_trl.manifest.platform_info`). On the same platform a re-flight
must reproduce every value to the bit; on another (another processor, ATen kernel path, BLAS or
torch) the last bits of the policy's and estimator's matrix products and reductions differ, so a
record of a kind whose deviations were measured small (:data:`CROSS_PLATFORM_RTOL`) must agree
within that tolerance, and any other, whose trajectories may diverge, must be shown equivalent
to its record within :data:`EQUIVALENCE_MARGIN` (:meth:`Agreement.equivalence`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import torch
from scipy import stats

from ..config import EnvConfig, MonitorConfig, config_from_dict
from ..envs import QuadWindEnv
from ..envs.runner import fly
from ..estimator import load_estimator
from ..manifest import CHECKPOINT_DIR, ROOT, platform_info, same_platform, same_processor
from ..quick import QuickFlights
from ..regimes import SWEEP_REGIME, SWEEPS
from ..rl.policy import load_policy
from .ablation import TRAINED_POLICY_KEYS, fly_controllers, policy_env_config
from .tracking import sweep_setup

METRICS = ("rmse_xy", "rmse_z")
#: The largest relative deviation of a per-episode RMSE accepted between two platforms on the same
#: processor model (another torch build, kernel path or environment), for the kinds of record
#: (sweep, quick) where one was measured to stay small; about 17x the largest measured on the quick
#: horizontal slice: ATen's scalar kernels (``ATEN_CPU_CAPABILITY=default``) against AVX-512 moved
#: values by at most 6.0e-6, AVX2 by 5.6e-6 (docs/simulator.md, "Exact replay"). It is no claim
#: between processor models: an AVX2-only AMD EPYC re-flying an AVX-512 record moved the policies'
#: values by up to 1.1e-3, and an Intel Xeon with AVX-512 re-flying the AVX-512 AMD EPYC record by
#: up to 1.8e-3; every other comparison (another processor, full-length flights, the quick vertical
#: slice, whose climbs carried a change of the estimator's softmax to 2.1e-2) is checked for
#: equivalence (:data:`EQUIVALENCE_MARGIN`).
CROSS_PLATFORM_RTOL: dict[tuple[str, bool], float] = {("horizontal", True): 1e-4}
#: The equivalence margin of every other cross-platform check, relative to the recorded mean of a
#: column (one controller's values): the 95 % interval of the mean paired difference (re-flown minus
#: recorded) must lie inside +-1 % of it. A test of "no difference" asks the wrong question here:
#: tiny systematic rounding, with a tight interval, rejects it, and among many columns one rejects it
#: by chance. The margin is about four times the largest *median* per-episode deviation measured
#: between vector instruction sets (2.3e-3, the quick vertical slice, where the estimator's softmax
#: rounds by the vector width) and far above the systematic shifts of a column's mean measured
#: between processors (docs/simulator.md, "Exact replay"); the gains the project reports are tens of
#: percent, so a shift inside it changes no claim.
EQUIVALENCE_MARGIN = 1e-2


@dataclass(frozen=True)
class Equivalence:
    """A re-flight's mean paired difference from its record and its 95 % interval (Student's t)
    against the equivalence bound (the margin times the recorded mean), in the record's units."""

    mean_difference: float
    low: float
    high: float
    bound: float

    @property
    def holds(self) -> bool:
        return -self.bound <= self.low and self.high <= self.bound

    def describe(self) -> str:
        if self.holds:
            verdict = "equivalent"
        elif self.low > self.bound or self.high < -self.bound:
            verdict = "NOT equivalent"
        else:
            verdict = "NOT shown equivalent (interval wider than the margin: fly more batches)"
        return (f"{verdict}: mean difference {self.mean_difference:+.2e}, 95 % interval "
                f"[{self.low:+.2e}, {self.high:+.2e}], margin +-{self.bound:.2e}")


@dataclass(frozen=True)
class Agreement:
    """Re-flown values against recorded ones (matched pairs): how many are identical, how far the
    others moved (relative to the recorded value) and whether any crash flag changed."""

    identical: int
    total: int
    relative: tuple[float, ...]  # per value, |flown - recorded| / |recorded|
    differences: tuple[float, ...]  # per value, flown - recorded
    flags_changed: int = 0
    recorded_sum: float = 0.0  # of the recorded values' magnitudes, for the equivalence margin

    @classmethod
    def of(cls, recorded: Sequence[float], flown: Sequence[float], recorded_flags: Sequence[bool] = (),
           flown_flags: Sequence[bool] = ()) -> "Agreement":
        if len(recorded) != len(flown) or len(recorded_flags) != len(flown_flags):
            raise ValueError(f"recorded and flown differ in length: {len(recorded)} vs {len(flown)} values, "
                             f"{len(recorded_flags)} vs {len(flown_flags)} flags")
        rel = tuple(abs(b - a) / abs(a) if a != 0 else (0.0 if b == 0 else math.inf) for a, b in zip(recorded, flown))
        return cls(identical=sum(a == b for a, b in zip(recorded, flown)), total=len(recorded), relative=rel,
                   differences=tuple(b - a for a, b in zip(recorded, flown)),
                   flags_changed=sum(a != b for a, b in zip(recorded_flags, flown_flags)),
                   recorded_sum=float(sum(abs(a) for a in recorded)))

    def __add__(self, other: "Agreement") -> "Agreement":
        return Agreement(self.identical + other.identical, self.total + other.total, self.relative + other.relative,
                         self.differences + other.differences, self.flags_changed + other.flags_changed,
                         self.recorded_sum + other.recorded_sum)

    @property
    def bitwise(self) -> bool:
        return self.identical == self.total and self.flags_changed == 0

    @property
    def max_relative(self) -> float:
        return max(self.relative, default=0.0)

    def equivalence(self, margin: float | None = None) -> "Equivalence":
        """The mean paired difference and its 95 % interval against ``margin`` (default
        :data:`EQUIVALENCE_MARGIN`) times the recorded mean: the check for flights on another
        platform, where a rounding difference can send one episode along another trajectory. With
        fewer than two values there is no interval: then only an exact match counts."""
        margin = EQUIVALENCE_MARGIN if margin is None else margin
        if not 0 < margin < 1:
            raise ValueError(f"margin={margin!r}; allowed: a relative margin in (0, 1)")
        n = len(self.differences)
        bound = margin * self.recorded_sum / max(n, 1)
        if n < 2:
            d = self.differences[0] if n else 0.0
            half = 0.0 if d == 0 else math.inf
            return Equivalence(d, d - half, d + half, bound)
        d = torch.tensor(self.differences, dtype=torch.float64)
        half = float(stats.t.ppf(0.975, n - 1)) * float(d.std()) / math.sqrt(n)
        mean = float(d.mean())
        return Equivalence(mean, mean - half, mean + half, bound)

    def describe(self) -> str:
        if self.bitwise:
            return f"{self.total}/{self.total} values bit-identical"
        rel = torch.tensor(self.relative, dtype=torch.float64)
        q = torch.quantile(rel, torch.tensor([0.5, 0.95], dtype=torch.float64)).tolist()
        d = torch.tensor(self.differences, dtype=torch.float64)
        return (f"{self.identical}/{self.total} values bit-identical; relative deviation median {q[0]:.1e}, "
                f"95th percentile {q[1]:.1e}, max {self.max_relative:.1e}; mean difference {d.mean():+.2e} "
                f"(sd {d.std() if len(d) > 1 else 0.0:.2e}); crash flags changed: {self.flags_changed}")


def replay_verdict(agreement: Agreement, recorded_platform: dict | None, rtol: float | None = None
                   ) -> tuple[bool, str]:
    """The reproducibility contract (docs/simulator.md, "Exact replay"): ``(holds, what was
    checked)``. Same platform: every value bit-identical. Another platform (or a record that names
    none): with ``rtol`` (the record kind's :data:`CROSS_PLATFORM_RTOL`) and the same processor
    model (:func:`~quadwind_trl.manifest.same_processor`), every value within it and no crash flag changed; otherwise
    equivalence within :data:`EQUIVALENCE_MARGIN` (:meth:`Agreement.equivalence`), the crash
    flags that changed reported beside it."""
    if same_platform(recorded_platform, platform_info()):
        return agreement.bitwise, f"bitwise (same platform): {agreement.describe()}"
    where = "other platform" if recorded_platform else "platform not recorded"
    if rtol is not None and not same_processor(recorded_platform, platform_info()):
        rtol, where = None, f"{where} on another processor"
    if rtol is None:
        equivalence = agreement.equivalence()
        return equivalence.holds, (f"{where}, equivalence within {EQUIVALENCE_MARGIN:.0%} of the recorded mean: "
                                   f"{equivalence.describe()}; {agreement.describe()}")
    ok = agreement.max_relative <= rtol and agreement.flags_changed == 0
    return ok, f"{where}, within {rtol:.0e} relative: {'yes' if ok else 'NO'}; {agreement.describe()}"


def replay(sweep_name: str, rows: slice, quick: bool, compile_step: bool | None = None,
           pattern_s: float | None = None) -> dict[str, dict[str, list[str]]]:
    """Per-controller, per-metric ``float.hex`` of every episode of ``rows`` of the sweep (the
    policies on the simulator step they trained on unless ``compile_step`` says otherwise;
    ``pattern_s`` shortens the fixed-altitude patterns further, for cheap checks)."""
    sweep, regime = SWEEPS[sweep_name], SWEEP_REGIME[sweep_name]
    scenarios, override = sweep_setup(sweep, quick)
    if pattern_s is not None:
        shorter, base = QuickFlights(pattern_s=pattern_s).config, override or (lambda cfg: cfg)
        override = lambda cfg: shorter(base(cfg))  # noqa: E731
    scenarios = scenarios[rows]
    n = scenarios.batch_size[0]
    pd_cfg = override(EnvConfig()) if override else EnvConfig()
    results = {"pd": fly(QuadWindEnv(pd_cfg, batch_size=[n]), scenarios, progress=False)}
    results.update(fly_controllers(regime, scenarios, CHECKPOINT_DIR / f"policy_{regime}.pt",
                                   load_estimator(regime), ("blind", "aware"), config_override=override,
                                   compile_step=compile_step))
    return {name: {m: [float(v).hex() for v in getattr(res, m).tolist()] for m in METRICS} | {
        "crashed": res.crashed.tolist()} for name, res in results.items()}


def compare_records(reference: dict, flown: dict) -> Agreement:
    """A record's ``results`` block (:func:`replay`'s output) against a re-flight of it."""
    agreement = Agreement.of([], [])
    for name, block in reference.items():
        for m in METRICS:
            agreement += Agreement.of([float.fromhex(v) for v in block[m]], [float.fromhex(v) for v in flown[name][m]])
        agreement += Agreement.of([], [], block["crashed"], flown[name]["crashed"])
    return agreement


def _recorded(path: str | Path) -> Path:
    """A checkpoint path as a results file records it: relative to the repository
    (``manifest.repo_relative``) unless it exists from here or is absolute."""
    path = Path(path)
    return path if path.is_absolute() or path.exists() else ROOT / path


def flown_quick(results: dict) -> bool:
    """Whether an ablation results file flew the ``--quick`` flights (older files only say so in
    their command)."""
    return bool(results.get("quick", "--quick" in results.get("command", "").split()))


def flown_monitor(results: dict) -> MonitorConfig | None:
    """The runtime monitor an ablation results file flew its policies with (``--monitor``; files
    without the entry flew none)."""
    recorded = results.get("monitor")
    return None if recorded is None else config_from_dict(MonitorConfig, recorded)


def verify_ablation(results: dict, chunks: range | None = None, policy_path=None, estimator_path=None
                    ) -> tuple[dict[str, Agreement], int]:
    """Re-fly batches ``chunks`` (default: all) of an ablation results file (``recipes/ablation.py``
    output) with its controllers, policy, estimator, flights (``--quick`` or not), simulator
    setting and batch layout, and compare every per-episode RMSE and crash flag with the file's
    episode table (the JSON holds each float32 RMSE exactly). Returns ``({controller: Agreement},
    episodes flown)``; :func:`replay_verdict` says whether it meets the contract.

    Only the recorded layout replays: the simulator's rows do not depend on the batch, but the
    estimator's and the policy's matrix products round differently at other batch sizes (a
    2-episode slice of a 10-episode batch re-flown alone differed in every policy RMSE), so the unit of
    a check is one recorded batch (``results["batch"]``; files without it flew all their
    episodes in one)."""
    sweep_name = results["sweep"]
    sweep, regime = SWEEPS[sweep_name], SWEEP_REGIME[sweep_name]
    quick = flown_quick(results)
    scenarios, override = sweep_setup(sweep, quick, flown_monitor(results))
    policy = _recorded(policy_path or results["policy"])
    # the separately trained policies the file records (files from before a controller existed lack its key)
    trained = {name: _recorded(results[key]) for name, key in TRAINED_POLICY_KEYS.items() if results.get(key) is not None}
    estimator = load_estimator(regime, estimator_path or results.get("estimator"),
                               config=policy_env_config(load_policy(policy)[1]))
    flown = fly_controllers(regime, scenarios, policy, estimator, tuple(results["controllers"]),
                            batch=results.get("batch", results["episodes"]), config_override=override,
                            compile_step=bool(results.get("compile_step", False)), chunks=chunks,
                            trained_policies=trained)
    table = results["episodes_table"]
    out, episodes = {}, 0
    for name, res in flown.items():
        rows = res.index.tolist()
        episodes = len(rows)
        agreement = Agreement.of([], [], [table[f"{name}_crashed"][r] for r in rows], res.crashed.tolist())
        for metric in ("rmse_xy", "rmse_z", "rmse"):
            agreement += Agreement.of([table[f"{name}_{metric}"][r] for r in rows], getattr(res, metric).tolist())
        out[name] = agreement
    return out, episodes
