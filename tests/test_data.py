"""Datasets (generation, determinism, interruption), the crop, the wind-case split, window
tables, the balanced sampler and the training-split statistics. All tiny."""
from __future__ import annotations

import filecmp
import os
import signal
import subprocess
import sys
import time
import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from filelock import FileLock
from scipy import stats
from tensordict.memmap import MemoryMappedTensor

import quadwind_trl.data.generate as generate_mod
from quadwind_trl.config import EnvConfig, TrajectoryConfig
from quadwind_trl.data import (
    CaseBalancedSampler,
    GenerationSpec,
    WindowDataset,
    compute_features,
    crop_start,
    generate_dataset,
    is_complete,
    load_dataset,
    prepare_windows,
    split_cases,
    window_table,
)
from quadwind_trl.data.generate import dataset_bytes
from quadwind_trl.data.windows import sample_stats, t_safety_s
from quadwind_trl.envs import RegimeRanges
from quadwind_trl.envs.sensors import sensor_widths
from quadwind_trl.envs.trajectories import trajectory_ids
from quadwind_trl.estimator.features import FeatureExtractor
from quadwind_trl.keys import MEAS_KEY

ROOT = Path(__file__).resolve().parent.parent


def tiny_spec(seed: int = 5) -> GenerationSpec:
    cfg = replace(EnvConfig(), trajectories=replace(TrajectoryConfig(), horizontal_duration_s=4.0))
    return GenerationSpec(regime="horizontal", cases=2, seed=seed, config=cfg, ranges=RegimeRanges(altitude_m=(10.0, 14.0)))


# the flights of micro_spec: armed at once, a short climb blend to 1-1.5 m, a 0.5 s pattern, and the
# unflown vertical and hover tables short (tables are built once per configuration and process;
# tests/test_outputs.py flies the same ones)
MICRO_TRAJECTORIES = replace(TrajectoryConfig(), horizontal_duration_s=0.5, arm_time_s=0.1, climb_blend_s=0.5,
                             vertical_top_m=10.0, hover_duration_s=1.0)


def micro_spec(seed: int = 9) -> GenerationSpec:
    """5 flights of under 2 s: for the tests that generate more than once. What they check (the
    same bytes at any batch, chunked commits, interruption, resume) does not depend on how long a
    flight is, their cost does (with flights of about 7 s they took about 100 s of CPU)."""
    cfg = replace(EnvConfig(), trajectories=MICRO_TRAJECTORIES)
    return GenerationSpec(regime="horizontal", cases=1, seed=seed, config=cfg, ranges=RegimeRanges(altitude_m=(1.0, 1.5)))


def generated_once(tmp_path_factory, name: str, spec: GenerationSpec, max_batch: int) -> Path:
    """A dataset generated once per run for the tests that only read it: under pytest-xdist the
    first worker to need it generates it, the others wait and read the same files (as a plain
    module fixture, every worker that ran one of its tests generated its own)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # this run's directory, above each worker's own
    out = (root / f"shared_{name}" / name).resolve()
    out.parent.mkdir(exist_ok=True)
    with FileLock(out.parent / "fixture.lock"):  # not generate_dataset's own lock: that one refuses, this one waits
        if not out.exists():
            generate_dataset(out, spec, max_batch=max_batch, progress=False)
    return out


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    return generated_once(tmp_path_factory, "tiny", tiny_spec(), max_batch=10)


@pytest.fixture(scope="module")
def micro_at_batch3(tmp_path_factory) -> Path:
    """:func:`micro_spec` generated uninterrupted at batch 3 (chunks of 3 and 2): the reference of
    both the batch-independence and the resume test (generated once for the two)."""
    return generated_once(tmp_path_factory, "whole", micro_spec(), max_batch=3)


def data_files(root: Path) -> list[Path]:
    return sorted(p.relative_to(root) for p in root.rglob("*") if p.is_file() and p.name != "provenance.json")


def test_dataset_layout(tiny):
    data, manifest = load_dataset(tiny)
    n = 2 * 5
    assert data.batch_size == (n,) and manifest["num_flights"] == n
    rec = data["record"]
    assert rec.batch_size[0] == n and rec.batch_size[1] == manifest["record_length"]
    assert {k: v.shape[-1] for k, v in rec[MEAS_KEY].items()} == sensor_widths()  # the sensors' named entries
    assert rec["mean_wind_ne"].shape[-1] == 2
    assert all(isinstance(v, MemoryMappedTensor) for v in data.values(True, True))  # lazy, on disk
    # the size the generator reports counts every tensor's whole length (memmaps may be sparse on disk)
    assert dataset_bytes(tiny) >= sum(v.numel() * v.element_size() for v in data.values(True, True))
    # valid samples are a prefix of the stored length; steps are every 10th control step
    t_idx = torch.arange(rec.batch_size[1])
    assert torch.equal(rec["valid"], t_idx < data["length"][:, None])
    assert torch.equal(rec["step"][0, :5, 0], torch.arange(5) * 10)
    # labels: the (north, east) components of the mean wind
    assert torch.all(rec["mean_wind_ne"][:, 0] != 0)
    assert torch.equal(data["case_id"], torch.arange(2).repeat_interleave(5))
    assert torch.equal(data["traj_id"], data["scenario", "traj_id"])
    assert manifest["trajectories"] == ["loiter_circle_h", "racetrack_h", "figure8_h", "cloverleaf_h", "lawnmower_h"]
    assert not bool(data["crashed"].any())


def test_generation_is_deterministic_and_batch_independent(tmp_path, micro_at_batch3):
    # --resume with nothing to resume is a fresh run
    first = generate_dataset(tmp_path / "first", micro_spec(), max_batch=5, progress=False, resume=True)
    again = micro_at_batch3  # the same spec in chunks of 3 and 2
    files = data_files(first)
    assert files == data_files(again)
    assert sum(str(f).endswith(".memmap") for f in files) > 20
    _, mismatch, errors = filecmp.cmpfiles(first, again, [str(f) for f in files], shallow=False)
    assert mismatch == [] and errors == []
    assert json.loads((again / "provenance.json").read_text())["env_batch"] == 3


class Interrupt(Exception):
    pass


def test_interrupted_generation_never_loads_and_resumes(tmp_path, micro_at_batch3):
    out = tmp_path / "cut"

    def stop(i):
        raise Interrupt

    # interrupted after its first chunk: nothing loads, the committed chunk stays for a resume
    with pytest.raises(Interrupt):
        generate_dataset(out, micro_spec(), max_batch=3, progress=False, after_chunk=stop)
    partial = generate_mod.partial_dir(out.resolve())
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == [partial.name]
    assert not is_complete(partial)
    for path in (out, partial):
        with pytest.raises(FileNotFoundError):
            load_dataset(path)
    flown = json.loads((partial / generate_mod.PROGRESS_FILE).read_text())["flown"]
    assert len(flown) == 3  # 5 flights at batch 3: chunks of 3 and 2
    # a resume flies only what is missing and gives the same bytes as an uninterrupted run
    chunks = []
    generate_dataset(out, micro_spec(), max_batch=3, progress=False, resume=True, after_chunk=chunks.append)
    assert len(chunks) == 1  # the first chunk was not flown again
    whole = micro_at_batch3  # the uninterrupted run at the same batch
    files = data_files(whole)
    _, mismatch, errors = filecmp.cmpfiles(out, whole, [str(f) for f in files], shallow=False)
    assert mismatch == [] and errors == [] and files == data_files(out)
    assert [p.name for p in tmp_path.iterdir()] == ["cut"]  # no partial left beside it


def test_interruption_before_a_chunk_removes_the_partial_and_other_specs_do_not_resume(tmp_path):
    out = tmp_path / "cut"
    with pytest.raises(Interrupt):
        generate_dataset(out, micro_spec(), max_batch=4, progress=False, after_chunk=lambda i: (_ for _ in ()).throw(Interrupt)
                         if i == 0 else None)
    with pytest.raises(ValueError, match="another spec or batch"):
        generate_dataset(out, micro_spec(), max_batch=5, progress=False, resume=True)
    # without --resume a stale partial run is replaced
    generate_dataset(out, micro_spec(), max_batch=5, progress=False)
    assert is_complete(out) and list(tmp_path.iterdir()) == [out]


GENERATE_MICRO = """
import sys
from tests.test_data import micro_spec
from quadwind_trl.data.generate import generate_dataset
generate_dataset(sys.argv[1], micro_spec(), max_batch=2, progress=False, resume=sys.argv[2] == "resume")
print("complete")
"""


def test_sigterm_keeps_committed_chunks_and_resume_finishes(tmp_path):
    """A real process, killed with SIGTERM once a chunk has been written, resumes."""
    out = tmp_path / "flights"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-c", GENERATE_MICRO, str(out)]
    proc = subprocess.Popen(cmd + ["fresh"], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    progress = generate_mod.partial_dir(out) / generate_mod.PROGRESS_FILE
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if progress.exists() and json.loads(progress.read_text())["flown"]:
            break
        time.sleep(0.05)
    assert proc.poll() is None, f"finished before it could be interrupted: {proc.communicate()}"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0 and not out.exists()
    assert "Interrupted: signal SIGTERM" in err and "--resume" in err and progress.exists()
    done = subprocess.run(cmd + ["resume"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "resuming flights" in done.stdout and "complete" in done.stdout and is_complete(out)
    assert [p.name for p in tmp_path.iterdir()] == ["flights"]


def test_existing_dataset_is_not_replaced_without_overwrite(tiny):
    with pytest.raises(FileExistsError):
        generate_dataset(tiny, tiny_spec(), progress=False)


def test_bad_regime_fails_early():
    with pytest.raises(ValueError, match="regime"):
        GenerationSpec(regime="diagonal")
    with pytest.raises(ValueError, match="altitude_m"):
        GenerationSpec(regime="vertical", ranges=RegimeRanges()).scenarios()


def test_crop_removes_exactly_the_climb(tiny):
    """With no settling margin the crop starts at the first sample of the pattern (the
    reference has reached the flight altitude); by default ``SETTLE_S`` = 2 s later."""
    data, manifest = load_dataset(tiny)
    traj = TrajectoryConfig(horizontal_duration_s=4.0)
    altitude = data["scenario", "altitude_m"].clone()
    exact = crop_start(data["traj_id"].clone(), altitude, traj, settle_s=0.0, t_min_s=0.0)
    assert torch.equal(exact, data["pattern_start_step"] // 10)
    ref_z = data["record", "ref_pos"][..., 2]
    for i in range(data.batch_size[0]):
        k = int(exact[i])
        # the first kept sample is the first one at or after the reference climb's end
        climb_end = traj.arm_time_s + float(altitude[i]) / traj.climb_rate_m_s + traj.climb_blend_s
        assert (k - 1) * 0.1 < climb_end <= k * 0.1 + 1e-6
        assert torch.all(ref_z[i, :10] == 0) and torch.all(ref_z[i, 10:k].diff() > 0)  # ground, then climbing
        assert torch.allclose(ref_z[i, k : int(data["length"][i])], altitude[i].expand(int(data["length"][i]) - k), atol=1e-4)
    default = crop_start(data["traj_id"].clone(), altitude, traj)
    assert torch.equal(default, exact + 20)
    assert t_safety_s(traj) == 6.0


def test_crop_formula_and_vertical_flights():
    traj = TrajectoryConfig()
    ids = trajectory_ids(["racetrack_h", "racetrack_h", "figure8_3d"])
    alt = torch.tensor([300.0, 3.0, 600.0])
    got = crop_start(ids, alt, traj)
    # 300 m: 100 s climb + 6 s; 3 m: 1 s + 6 s < t_min = 8 s; vertical: the climb is the flight
    assert got.tolist() == [1060, 80, 80]


def test_split_holds_out_wind_cases():
    cases = torch.arange(1000).repeat_interleave(5)
    parts = split_cases(cases)
    sizes = {k: v.numel() for k, v in parts.items()}
    assert sizes == {"train": 700, "val": 150, "test": 150}
    allc = torch.cat(list(parts.values()))
    assert torch.equal(torch.sort(allc).values, torch.arange(1000))  # disjoint and complete
    again = split_cases(cases)
    assert all(torch.equal(parts[k], again[k]) for k in parts)  # fixed seed
    other = split_cases(cases, seed=1)
    assert not torch.equal(parts["train"], other["train"])
    with pytest.raises(ValueError, match="fractions"):
        split_cases(cases, (0.5, 0.2, 0.2))


def test_window_table_is_index_based_and_inside_the_crop():
    flights = torch.tensor([4, 7, 9])
    start = torch.tensor([10, 0, 50])
    length = torch.tensor([100, 59, 121])
    table = window_table(flights, start, length, window=60, stride=12)
    # flight 4: ends 69, 81, 93; flight 7: too short; flight 9: ends 109 (121 - 1 = 120 < 121)
    assert table.tolist() == [[4, 69], [4, 81], [4, 93], [9, 109]]
    feats = torch.arange(10 * 130 * 2, dtype=torch.float32).reshape(10, 130, 2)
    labels = torch.randn(10, 130, 2)
    ds = WindowDataset(feats, labels, table)
    x, y = ds[1]
    assert torch.equal(x, feats[4, 22:82]) and torch.equal(y, labels[4, 81])
    batch = ds.__getitems__([0, 3])
    assert torch.equal(batch[1][0], feats[9, 50:110])


def test_balanced_sampler_draws_cases_uniformly():
    counts = torch.tensor([1, 3, 10, 40, 200, 5, 2, 80, 20, 7])
    window_case = torch.repeat_interleave(torch.arange(10) * 3 + 100, counts)  # arbitrary ids
    window_case = window_case[torch.randperm(window_case.numel(), generator=torch.Generator().manual_seed(0))]
    sampler = CaseBalancedSampler(window_case, num_samples=20000, seed=3)
    idx = torch.tensor(list(sampler))
    assert len(idx) == 20000 and idx.min() >= 0 and idx.max() < window_case.numel()
    drawn = torch.bincount(window_case[idx] - 100)[::3]
    assert drawn.sum() == 20000
    _, p = stats.chisquare(drawn.numpy())
    assert p > 1e-3, drawn
    # a proportional sampler would have drawn case 4 (200 of 368 windows) ~54 % of the time
    assert drawn[4] < 0.15 * 20000
    # within a case, windows are uniform
    in_case = idx[window_case[idx] == 4 * 3 + 100]
    _, counts_in = torch.unique(in_case, return_counts=True)
    assert counts_in.numel() > 150
    # seeded and epoch-dependent
    assert torch.equal(idx, torch.tensor(list(CaseBalancedSampler(window_case, num_samples=20000, seed=3))))
    sampler.set_epoch(1)
    assert not torch.equal(idx, torch.tensor(list(sampler)))


def test_stats_from_training_split_only():
    gen = torch.Generator().manual_seed(0)
    values = torch.randn(6, 50, 3, generator=gen) * torch.tensor([1.0, 2.0, 0.0]) + 5.0
    flights = torch.tensor([0, 2, 3])
    start = torch.tensor([5, 0, 10])
    length = torch.tensor([50, 20, 40])
    st = sample_stats(values, flights, start, length)
    pooled = torch.cat([values[0, 5:50], values[2, 0:20], values[3, 10:40]])
    assert torch.allclose(st.mean, pooled.mean(0), atol=1e-5)
    assert torch.allclose(st.std[:2], pooled.std(0, unbiased=False)[:2], atol=1e-5)
    assert st.std[2] == 1.0  # a constant channel is left unscaled
    values[1] += 100.0  # a non-training flight changes nothing
    values[0, :5] += 100.0  # nor does the cropped part of a training flight
    st2 = sample_stats(values, flights, start, length)
    assert torch.equal(st.mean, st2.mean) and torch.equal(st.std, st2.std)


def test_features_and_windows_of_a_generated_dataset(tiny, tmp_path):
    data, manifest = load_dataset(tiny)
    fx = FeatureExtractor.from_config("horizontal")
    cached = compute_features(data["record"], fx, out=tmp_path / "h.memmap", chunk=4)
    assert torch.equal(cached, compute_features(data["record"], fx, out=tmp_path / "h.memmap"))  # reloads
    with pytest.raises(ValueError, match="holds features of another extractor"):  # other trailing means: other channels
        compute_features(data["record"], FeatureExtractor.from_config("horizontal", windows=(100,)), out=tmp_path / "h.memmap")
    # a vertical cache written before that schema had trailing means recorded an unused windows entry: still its cache
    vfx = FeatureExtractor.from_config("vertical")
    vertical = compute_features(data["record"], vfx, out=tmp_path / "v.memmap")
    sidecar = tmp_path / "v.memmap.json"
    old = json.loads(sidecar.read_text())
    old["extractor"]["windows"] = [100, 300]
    sidecar.write_text(json.dumps(old))
    assert torch.equal(compute_features(data["record"], vfx, out=tmp_path / "v.memmap"), vertical)
    # online, the way a transform sees it: one contiguous tick per call, all flights at once
    state = fx.init_state(data.batch_size[0])
    rec = data["record"]
    for t in range(rec.batch_size[1]):
        state, f = fx.step(state, {k: rec[k][:, t].clone() for k in fx.raw_keys})
        assert torch.equal(f, cached[:, t])
    # these flights cruise for 4 s only: 20-sample windows
    wd = prepare_windows(data, manifest, cached, fx.channels, window=20, stride=5, settle_s=0.0, fractions=(0.5, 0.0, 0.5))
    train_cases = set(wd.window_cases("train").tolist())
    test_cases = set(wd.window_cases("test").tolist())
    assert train_cases and test_cases and not (train_cases & test_cases)
    for table in wd.tables.values():
        assert torch.all(table[:, 1] - 19 >= wd.crop[table[:, 0]])
        assert torch.all(table[:, 1] < wd.length[table[:, 0]])
    x, y = wd.dataset("train")[0]
    assert x.shape == (20, 48) and y.shape == (2,)
    f0, e0 = wd.tables["train"][0].tolist()
    assert torch.allclose(x, wd.feature_stats(cached[f0, e0 - 19 : e0 + 1]))
    assert torch.equal(y, data["record", "mean_wind_ne"][f0, e0])


def test_describe_summarises_a_dataset_in_two_lines():
    """What recipes/generate_flights.py prints after a run: counts, record shape and rate, flight
    lengths (the record's valid samples), crashes and PD's median RMSEs."""
    from tensordict import TensorDict

    data = TensorDict({"length": torch.tensor([150, 250, 200]), "crashed": torch.tensor([False, True, False]),
                       "rmse_xy": torch.tensor([0.2, 0.9, 0.4]), "rmse_z": torch.tensor([0.1, 0.3, 0.2])}, batch_size=[3])
    manifest = {"regime": "horizontal", "num_flights": 3, "cases": 1, "trajectories": ["a", "b", "c"], "record_length": 300,
                "record_dt_s": 0.1}
    assert generate_mod.describe(data, manifest).splitlines() == [
        "horizontal: 3 flights = 1 cases x 3 trajectories, record [3, 300] at 10 Hz",
        "flight length 15.0-25.0 s, crashed 1, PD rmse_xy median 0.400 m, rmse_z median 0.200 m"]
