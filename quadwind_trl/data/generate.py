"""Flight-log datasets: LHS wind cases x trajectories, flown by the PD baseline, stored as
memory-mapped tensordicts.

A dataset is one directory::

    DIR/
      data/               TensorDict.memmap_ of batch [n] (one row per flight):
        record/           [n, T] 10 Hz record: raw channels (features.RAW_RECORD_KEYS; the sensors
                          as the nested named entries "meas/gps_pos", ...), "step",
                          labels "mean_wind_ne" [2] (north, east), truth "wind" [3] (total air
                          velocity, ENU), "pos" [3] (true position, ENU), "valid" (bool)
        scenario/         [n] every SCENARIO_FIELDS entry (replays the flight exactly)
        case_id, traj_id, length, pattern_start_step, end_step, rmse_xy, rmse_z, crashed
      manifest.json       regime, seeds, sizes, trajectory names, full EnvConfig and RegimeRanges
                          (deterministic: no timestamps)
      provenance.json     command, git commit, wall time, host threads (differs between runs)
      COMPLETE            written last, after everything it covers: the size of every file of
                          data/ and of manifest.json (JSON, deterministic). A dataset without it,
                          or with a listed file missing or of another size, is never loaded.

Generation writes into ``.<name>.partial`` beside ``DIR`` and renames it into place only when
everything, ``COMPLETE`` included, is written, so an interrupted run never leaves anything that
:func:`load_dataset` accepts. Chunks (one env batch of flights each) are committed one by one:
after a chunk's rows are written, ``progress.json`` in the partial directory records them
(atomically). Interrupted (SIGINT, SIGTERM or an error) after at least one chunk, the partial
directory stays for ``resume=True`` (``--resume``) to continue from the last committed chunk;
interrupted before, it is removed. A run without ``resume`` starts over. Same arguments => byte-identical ``data/``,
``manifest.json`` and ``COMPLETE`` (the physics is a function of the scenarios; the scenarios of the seeds).

A generation holds :class:`~quadwind_trl.outputs.OutputLock` on ``DIR`` from its first check to the
rename, so a second run on the same ``DIR`` (a resume included) is refused at once instead of
racing the first one for the partial directory.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, Literal

import torch
from tensordict import TensorDict

from ..manifest import git_commit, platform_info, write_json
from ..outputs import OutputLock
from ..config import EnvConfig, TrajectoryConfig, config_to_dict
from ..envs.quad_env import QuadWindEnv
from ..envs.runner import iter_flights
from ..envs.scenarios import SCENARIO_FIELDS, RegimeRanges, cross_with_trajectories, sample_regimes
from ..envs.trajectories import HORIZONTAL, VERTICAL, trajectory_names
from ..regimes import HORIZONTAL_DATASET, VERTICAL_DATASET
from ..estimator.features import RAW_RECORD_KEYS, raw_record_template

Regime = Literal["horizontal", "vertical"]

COMPLETE_MARKER = "COMPLETE"
# 2: the sensors stored as named entries under record/meas (format 1, a packed [16] "meas", is
# not read: regenerate)
FORMAT_VERSION = 2

#: what the runner logs (env observation keys) -> the name stored in ``record``
LOG_KEYS: tuple = RAW_RECORD_KEYS + ("step", ("truth", "pos"), ("truth", "wind"), ("truth", "mean_wind"))


@dataclass(frozen=True)
class GenerationSpec:
    """Everything that defines a dataset's content."""

    regime: Regime = "horizontal"
    cases: int = 1000  # paper: 1000 wind cases per regime
    seed: int = 0  # LHS design seed (turbulence and sensor seeds derive from it per case)
    config: EnvConfig = field(default_factory=EnvConfig)
    ranges: RegimeRanges | None = None  # None: RegimeRanges() horizontal, altitude_m=None vertical

    def __post_init__(self):
        if self.regime not in ("horizontal", "vertical"):
            raise ValueError(f"GenerationSpec.regime={self.regime!r}; allowed: 'horizontal', 'vertical'")
        if self.cases < 1:
            raise ValueError(f"GenerationSpec.cases={self.cases} must be >= 1")

    @property
    def trajectories(self) -> tuple[str, ...]:
        return HORIZONTAL if self.regime == "horizontal" else VERTICAL

    @property
    def regime_ranges(self) -> RegimeRanges:
        if self.ranges is not None:
            return self.ranges
        return HORIZONTAL_DATASET if self.regime == "horizontal" else VERTICAL_DATASET

    def scenarios(self) -> TensorDict:
        """``cases x trajectories`` scenarios, case-major, with ``case_id``."""
        ranges = self.regime_ranges
        if (ranges.altitude_m is None) != (self.regime == "vertical"):
            raise ValueError(
                f"RegimeRanges.altitude_m={ranges.altitude_m!r} does not fit the {self.regime} regime "
                "(vertical designs take altitude_m=None, horizontal ones a range)"
            )
        return cross_with_trajectories(sample_regimes(self.cases, ranges, self.seed), self.trajectories)


def quick_spec(regime: Regime, seed: int = 0, cases: int = 3) -> tuple[GenerationSpec, list[str]]:
    """A tiny dataset for smoke tests: few cases, short flights. Returns the spec and a list of
    human-readable lines saying what differs from the paper-size dataset."""
    traj = replace(TrajectoryConfig(), horizontal_duration_s=15.0, vertical_top_m=20.0)
    cfg = replace(EnvConfig(), trajectories=traj)
    changes = [
        f"cases: 1000 -> {cases}",
        f"TrajectoryConfig.horizontal_duration_s: {TrajectoryConfig.horizontal_duration_s} -> {traj.horizontal_duration_s}",
        f"TrajectoryConfig.vertical_top_m: {TrajectoryConfig.vertical_top_m} -> {traj.vertical_top_m}",
    ]
    ranges = None
    if regime == "horizontal":
        ranges = RegimeRanges(altitude_m=(15.0, 25.0))
        changes.append(f"RegimeRanges.altitude_m: {RegimeRanges.altitude_m} -> {ranges.altitude_m}")
    return GenerationSpec(regime=regime, cases=cases, seed=seed, config=cfg, ranges=ranges), changes


def _record_template(n: int, t_len: int) -> TensorDict:
    """Zero-storage (expanded) template of the dataset layout, for ``memmap_like``."""

    def z(*shape, dtype=torch.float32):
        return torch.zeros((1,) * len(shape), dtype=dtype).expand(*shape)

    rec = raw_record_template(n, t_len).update(
        dict(
            step=z(n, t_len, 1, dtype=torch.int64),
            pos=z(n, t_len, 3),
            wind=z(n, t_len, 3),
            mean_wind_ne=z(n, t_len, 2),
            valid=z(n, t_len, dtype=torch.bool),
        )
    )
    scenario = {k: z(n, dtype=dtype) for k, (dtype, _) in SCENARIO_FIELDS.items()}
    return TensorDict(
        {
            "record": rec,
            "scenario": TensorDict(scenario, batch_size=[n]),
            "case_id": z(n, dtype=torch.int64),
            "traj_id": z(n, dtype=torch.int64),
            "length": z(n, dtype=torch.int64),
            "pattern_start_step": z(n, dtype=torch.int64),
            "end_step": z(n, dtype=torch.int64),
            "rmse_xy": z(n),
            "rmse_z": z(n),
            "crashed": z(n, dtype=torch.bool),
        },
        batch_size=[n],
    )


def _balanced_batch(num_flights: int, max_batch: int) -> int:
    """The env batch that flies ``num_flights`` in the fewest chunks with the least padding."""
    chunks = -(-num_flights // max_batch)
    return -(-num_flights // chunks)


PROGRESS_FILE = "progress.json"


class Interrupted(KeyboardInterrupt):
    """SIGTERM during generation, raised like Ctrl-C so the same cleanup runs."""


@contextmanager
def _terminate_as_interrupt():
    """SIGTERM raises :class:`Interrupted` (SIGINT already raises ``KeyboardInterrupt``) while
    generating, so the partial directory is kept for a resume or removed, never left half-known."""
    if threading.current_thread() is not threading.main_thread():  # signals reach the main thread only
        yield
        return

    def handler(signum, frame):
        raise Interrupted(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def generate_dataset(
    out: str | os.PathLike,
    spec: GenerationSpec,
    *,
    max_batch: int = 2048,
    device: str | torch.device = "cpu",
    compile_step: bool = False,
    overwrite: bool = False,
    resume: bool = False,
    progress: bool = True,
    command: str | None = None,
    after_chunk: Callable[[int], None] | None = None,
) -> Path:
    """Fly ``spec``'s scenarios with the PD baseline and write the dataset to ``out``.

    ``resume``: continue an interrupted run of the same spec and batch from its last committed
    chunk (a partial directory of another spec is an error; none: start fresh).
    ``after_chunk(i)`` is called after chunk ``i`` is committed (tests use it to interrupt).
    Returns the final path. Refuses to replace an existing dataset unless ``overwrite``.
    """
    if max_batch < 1:
        raise ValueError(f"max_batch={max_batch} must be >= 1")
    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    with OutputLock(out, "dataset", "wait for it to finish, or choose another out (--out)"), _terminate_as_interrupt():
        if out.exists() and not overwrite:
            raise FileExistsError(f"{out} exists; pass overwrite=True (--overwrite) to replace it")
        return _generate(out, partial_dir(out), spec, max_batch, device, compile_step, resume, progress, command, after_chunk)


def partial_dir(out: Path) -> Path:
    """Where an unfinished dataset for ``out`` is written."""
    return out.parent / f".{out.name}.partial"


def _generate(out: Path, tmp: Path, spec: GenerationSpec, max_batch: int, device, compile_step: bool, resume: bool,
              progress: bool, command: str | None, after_chunk: Callable[[int], None] | None) -> Path:
    t0 = time.perf_counter()
    scenarios = spec.scenarios()
    n = scenarios.batch_size[0]
    batch = _balanced_batch(n, max_batch)
    env = QuadWindEnv(spec.config, batch_size=[batch], device=device, compile_step=compile_step)
    traj = env.sim.trajectories
    log_every = spec.config.timing.log_every_control_steps
    pattern_start, end_step = traj.schedule(scenarios["traj_id"].to(env.device), scenarios["altitude_m"].to(env.device))
    pattern_start, end_step = pattern_start.cpu(), end_step.cpu()
    t_len = int(end_step.max()) // log_every + 1  # every flight starts on the ground (start_step 0)
    if bool((scenarios["start_step"] != 0).any()):
        raise ValueError("dataset flights start on the ground: scenario start_step must be 0")

    # what a resumed run must share with the interrupted one (the chunks depend on the batch)
    fingerprint = {"format_version": FORMAT_VERSION, "regime": spec.regime, "cases": spec.cases, "seed": spec.seed,
                   "config": config_to_dict(spec.config), "ranges": asdict(spec.regime_ranges), "env_batch": batch}
    flown = _resume_point(tmp, fingerprint, n) if resume else None
    if flown is None and tmp.exists():
        shutil.rmtree(tmp)  # a stale partial run without --resume: start over
    try:
        if flown is None:
            tmp.mkdir(parents=True)
            data = _record_template(n, t_len).memmap_like(tmp / "data", num_threads=0)
            data["scenario"].update_(scenarios.select(*SCENARIO_FIELDS))
            data["case_id"].copy_(scenarios["case_id"])
            data["traj_id"].copy_(scenarios["traj_id"])
            data["pattern_start_step"].copy_(pattern_start)
            data["end_step"].copy_(end_step)
            flown = torch.zeros(n, dtype=torch.bool)
            _commit(tmp, fingerprint, flown)
        else:
            data = TensorDict.load_memmap(tmp / "data")
            print(f"resuming {out.name}: {int(flown.sum())}/{n} flights already flown", flush=True)
        rec = data["record"]
        flights = iter_flights(env, scenarios, policy=None, log_keys=LOG_KEYS, progress=progress, skip=flown)
        for i, part in enumerate(flights):
            idx = part.index
            log = part.log
            length = log.batch_size[1]
            mean_wind = log.get(("truth", "mean_wind"))
            chunk = TensorDict(
                {k: log.get(k) for k in RAW_RECORD_KEYS + ("step", "valid")},
                batch_size=log.batch_size,
            )
            chunk.update(
                pos=log.get(("truth", "pos")),
                wind=log.get(("truth", "wind")),
                mean_wind_ne=torch.stack((mean_wind[..., 1], mean_wind[..., 0]), -1),
            )
            # past its end, every flight repeats its last valid sample (what the env simulates
            # after truncation depends on the chunk, so it is not kept: batch-independent data)
            valid_len = chunk["valid"].sum(1)
            t_idx = torch.arange(length).clamp_max(valid_len[:, None] - 1)
            rows = torch.arange(idx.numel())[:, None].expand_as(t_idx)
            chunk = chunk.apply(lambda v: v[rows, t_idx], batch_size=chunk.batch_size)
            chunk["valid"] = torch.arange(length) < valid_len[:, None]
            rec[idx, :length] = chunk
            if length < t_len:
                tail = chunk[:, -1:].expand(idx.numel(), t_len - length).clone()
                tail["valid"] = torch.zeros_like(tail["valid"])
                rec[idx, length:] = tail
            data["length"][idx] = valid_len
            data["rmse_xy"][idx] = part.rmse_xy
            data["rmse_z"][idx] = part.rmse_z
            data["crashed"][idx] = part.crashed
            flown[idx] = True
            _commit(tmp, fingerprint, flown)
            if after_chunk is not None:
                after_chunk(i)

        manifest = {
            "format_version": FORMAT_VERSION,
            "regime": spec.regime,
            "cases": spec.cases,
            "seed": spec.seed,
            "num_flights": n,
            "record_length": t_len,
            "record_dt_s": spec.config.timing.log_dt_s,
            "trajectories": list(spec.trajectories),
            # the stored traj_id values mean these names (load_dataset checks them against the registry)
            "trajectory_ids": {name: trajectory_names().index(name) for name in spec.trajectories},
            "raw_record_keys": list(RAW_RECORD_KEYS),
            "ranges": asdict(spec.regime_ranges),
            "config": config_to_dict(spec.config),
            "crashed": int(data["crashed"].sum()),
        }
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
        provenance = {
            "command": command,
            "git_commit": git_commit(),
            "platform": platform_info(),
            "wall_time_s": round(time.perf_counter() - t0, 2),
            "env_batch": batch,
            "compile_step": compile_step,
            "device": str(device),
            "torch_threads": torch.get_num_threads(),
            "created_unix": int(time.time()),
        }
        (tmp / "provenance.json").write_text(json.dumps(provenance, indent=1, sort_keys=True) + "\n")
        (tmp / PROGRESS_FILE).unlink()
        del data, rec
        write_json(tmp / COMPLETE_MARKER, {"files": _covered_files(tmp)})
        _fsync_tree(tmp)
        if out.exists():  # overwrite: swap, then delete the old one
            old = out.parent / f".{out.name}.old-{os.getpid()}"
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException as err:
        done = int(flown.sum()) if flown is not None else 0
        if done and (tmp / PROGRESS_FILE).exists():
            print(f"\ninterrupted ({type(err).__name__}) after {done}/{n} flights; {tmp} is kept: rerun with "
                  "--resume (resume=True) to continue, or delete it", file=sys.stderr, flush=True)
        else:
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _commit(tmp: Path, fingerprint: dict, flown: torch.Tensor) -> None:
    """Record the flights whose rows are written (the chunk's memmap writes precede this)."""
    write_json(tmp / PROGRESS_FILE, {"fingerprint": fingerprint, "flown": flown.nonzero().squeeze(-1).tolist()})


def _resume_point(tmp: Path, fingerprint: dict, n: int) -> torch.Tensor | None:
    """The flights an interrupted run of the same spec committed (None: nothing to resume)."""
    path = tmp / PROGRESS_FILE
    if not path.is_file():
        return None
    saved = json.loads(path.read_text())
    if saved["fingerprint"] != json.loads(json.dumps(fingerprint, default=str)):
        raise ValueError(f"{tmp} holds an interrupted run of another spec or batch; delete it or rerun with its arguments")
    flown = torch.zeros(n, dtype=torch.bool)
    flown[torch.tensor(saved["flown"], dtype=torch.int64)] = True
    return flown


def _fsync_tree(root: Path) -> None:
    for path in sorted(root.rglob("*")):
        if path.is_file():
            with open(path, "rb") as f:
                os.fsync(f.fileno())


def _covered_files(root: Path) -> dict[str, int]:
    """What ``COMPLETE`` vouches for: the size of every file of ``data/`` and of ``manifest.json``
    (sizes, not hashes: checking them costs a directory walk, so every load can afford it;
    ``provenance.json`` is the run's record, not data)."""
    files = [p for p in (root / "data").rglob("*") if p.is_file()] + [root / "manifest.json"]
    return {p.relative_to(root).as_posix(): p.stat().st_size for p in sorted(files)}


def dataset_problems(path: str | os.PathLike) -> list[str]:
    """What keeps ``path`` from being a complete dataset (empty: it is one): no ``COMPLETE``
    marker, or a file it lists missing or of another size. A marker written before markers
    listed files (``ok``) vouches for ``manifest.json`` and ``data/meta.json`` being there."""
    path = Path(path)
    marker = path / COMPLETE_MARKER
    if path.name.startswith("."):
        return [f"{path.name} is the generator's working directory (an unfinished or replaced dataset)"]
    if not marker.is_file():
        return [f"no {COMPLETE_MARKER} marker (missing, interrupted or still being written)"]
    text = marker.read_text()
    listed = json.loads(text)["files"] if text.startswith("{") else {"manifest.json": None, "data/meta.json": None}
    problems = []
    for name, size in listed.items():
        file = path / name
        if not file.is_file():
            problems.append(f"{name} is missing")
        elif size is not None and file.stat().st_size != size:
            problems.append(f"{name} has {file.stat().st_size} bytes, {COMPLETE_MARKER} lists {size}")
    return problems


def is_complete(path: str | os.PathLike) -> bool:
    return not dataset_problems(path)


def load_dataset(path: str | os.PathLike) -> tuple[TensorDict, dict]:
    """``(data, manifest)`` of a complete dataset; ``data`` is memory-mapped (read lazily). A
    dataset that is not (:func:`dataset_problems`) raises ``FileNotFoundError`` naming what is
    missing or wrong."""
    path = Path(path)
    problems = dataset_problems(path)
    if problems:
        shown = "; ".join(problems[:5]) + (f"; and {len(problems) - 5} more" if len(problems) > 5 else "")
        raise FileNotFoundError(f"{path} is not a complete dataset: {shown}. Generate it again "
                                "(recipes/generate_flights.py --overwrite, or --resume if it was interrupted)")
    manifest = json.loads((path / "manifest.json").read_text())
    if manifest.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{path}: dataset format {manifest.get('format_version')}, this code reads {FORMAT_VERSION}")
    _check_trajectory_ids(path, manifest["trajectory_ids"])
    return TensorDict.load_memmap(path / "data"), manifest


def _check_trajectory_ids(path: Path, stored: dict[str, int]) -> None:
    """The dataset's ``traj_id`` values mean the manifest's names: they must be registered under
    the same ids now (a user pattern registered in another order would change its id)."""
    names = trajectory_names()
    differ = {name: i for name, i in stored.items() if (names.index(name) if name in names else None) != i}
    if differ:
        raise ValueError(f"{path}: trajectory ids {differ} (manifest 'trajectory_ids') are not the registered ones "
                         f"({', '.join(f'{i} {n}' for i, n in enumerate(names))}); register the dataset's patterns "
                         "in the order they were registered when it was made")


def describe(data: TensorDict, manifest: dict) -> str:
    """A few summary lines about a dataset."""
    length = data["length"]
    dt = manifest["record_dt_s"]
    lines = [
        f"{manifest['regime']}: {manifest['num_flights']} flights = {manifest['cases']} cases x "
        f"{len(manifest['trajectories'])} trajectories, record [{manifest['num_flights']}, {manifest['record_length']}] at {1 / dt:.0f} Hz",
        f"flight length {float(length.min()) * dt:.1f}-{float(length.max()) * dt:.1f} s, "
        f"crashed {int(data['crashed'].sum())}, PD rmse_xy median {float(data['rmse_xy'].median()):.3f} m, "
        f"rmse_z median {float(data['rmse_z'].median()):.3f} m",
    ]
    return "\n".join(lines)


def dataset_bytes(path: str | os.PathLike) -> int:
    """Logical size of the dataset's files (memmaps may be sparse on disk)."""
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())

