"""One writer per output, and complete means complete: a second writer of a dataset or
a training run is refused at once with a message naming the output and the holder; a run killed
with SIGKILL leaves no stale lock and resumes without losing what it finished; a dataset missing a
file, or holding one of another size, names it; a resumed training run's logs neither repeat nor
skip a row."""
from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Iterator

import pytest
import torch
from tensordict import TensorDict

import quadwind_trl.data.generate as generate_mod
from quadwind_trl.config import EnvConfig, TrajectoryConfig
from quadwind_trl.data import GenerationSpec, generate_dataset, is_complete, load_dataset
from quadwind_trl.envs import RegimeRanges
from quadwind_trl.outputs import OutputInUse, OutputLock, lock_path, truncate_scalar_logs

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore"}
# every flight here uses these trajectories: their tables are built once per process (seconds)
TINY = replace(TrajectoryConfig(), horizontal_duration_s=0.5, arm_time_s=0.1, climb_blend_s=0.5, vertical_top_m=10.0,
               hover_duration_s=1.0)


def one_case_spec() -> GenerationSpec:
    """5 flights of under 2 s (the smallest horizontal dataset): 2 chunks at batch 3."""
    return GenerationSpec(regime="horizontal", cases=1, seed=9, config=replace(EnvConfig(), trajectories=TINY),
                          ranges=RegimeRanges(altitude_m=(1.0, 1.5)))


HOLD = """
import sys
from quadwind_trl.outputs import OutputLock
with OutputLock(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.readline()
"""


@contextmanager
def held_by_another_process(output: Path) -> Iterator[subprocess.Popen]:
    """A process holding ``output``'s lock until the block ends (or it is killed)."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(output)], cwd=ROOT, env=ENV, text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert proc.stdout.readline().strip() == "held"
        yield proc
    finally:
        proc.communicate("go\n" if proc.poll() is None else None, timeout=60)


def assert_names_the_holder(message: str, output: Path, pid: int, *words: str) -> None:
    for part in (str(output), f"PID {pid}", "since", *words):
        assert part in message, (part, message)


# --- the lock itself -------------------------------------------------------------------------


def test_the_lock_refuses_a_second_writer_and_dies_with_its_holder(tmp_path):
    out = tmp_path / "results.json"
    with held_by_another_process(out) as holder:
        with pytest.raises(OutputInUse) as refused:
            OutputLock(out, "results file", "wait for it to finish, or choose another --out").acquire()
        assert_names_the_holder(str(refused.value), out, holder.pid, "python -c", "results file", "choose another --out")
        assert isinstance(refused.value, FileExistsError)  # the commands' "exists" handlers report it
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=60)
    # the OS dropped the lock with its process: the stale file is taken over, then removed
    assert lock_path(out).exists()
    with OutputLock(out):
        assert json.loads(lock_path(out).read_text())["pid"] == os.getpid()
        with pytest.raises(OutputInUse, match="this process"):  # a second writer in this process too
            OutputLock(out).acquire()
    assert list(tmp_path.iterdir()) == []


# --- datasets --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def raced_dataset(tmp_path_factory) -> dict:
    """The issue's first reproduction: once the first chunk of a generation (this process) is
    written, ``generate_flights.py --resume`` on the same dataset, and the library call; then
    the first generation finishes."""
    out = tmp_path_factory.mktemp("raced") / "flights"
    second = {}

    def race(chunk: int) -> None:
        if chunk == 0:
            second["recipe"] = subprocess.run(
                [sys.executable, str(ROOT / "recipes" / "generate_flights.py"), "--regime", "horizontal", "--quick", "--cases",
                 "8", "--batch", "10", "--seed", "777", "--resume", "--out", str(out), "--no-progress"],
                cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=300,
            )  # fmt: skip
            with pytest.raises(OutputInUse) as refused:
                generate_dataset(out, one_case_spec(), max_batch=3, progress=False, resume=True)
            second["library"] = str(refused.value)

    generate_dataset(out, one_case_spec(), max_batch=3, progress=False, after_chunk=race)
    return {"out": out, **second}


def test_a_second_dataset_writer_is_refused_and_the_first_finishes_intact(raced_dataset):
    out, recipe = raced_dataset["out"], raced_dataset["recipe"]
    assert recipe.returncode != 0 and "resuming" not in recipe.stdout
    assert_names_the_holder(recipe.stderr, out.resolve(), os.getpid(), "dataset", "--out")
    assert_names_the_holder(raced_dataset["library"], out.resolve(), os.getpid(), "this process", "dataset")
    data, manifest = load_dataset(out)
    assert manifest["num_flights"] == 5 and bool((data["length"] > 0).all())
    assert sorted(p.name for p in out.parent.iterdir()) == ["flights"]  # no partial, no lock file left


def test_a_dataset_missing_a_file_or_holding_a_cut_one_names_it(raced_dataset, tmp_path):
    listed = json.loads((raced_dataset["out"] / "COMPLETE").read_text())["files"]
    assert "manifest.json" in listed and "data/meta.json" in listed and "provenance.json" not in listed
    removed, cut = tmp_path / "removed", tmp_path / "cut"
    shutil.copytree(raced_dataset["out"], removed)
    (removed / "data" / "record" / "wind.memmap").unlink()
    shutil.copytree(raced_dataset["out"], cut)
    size = (cut / "data" / "rmse_xy.memmap").stat().st_size
    os.truncate(cut / "data" / "rmse_xy.memmap", size - 4)
    no_data = tmp_path / "no_data"  # what the race left: marker and manifests, no data/
    shutil.copytree(raced_dataset["out"], no_data, ignore=shutil.ignore_patterns("data"))
    for path, words in ((removed, ["data/record/wind.memmap is missing"]),
                        (cut, [f"data/rmse_xy.memmap has {size - 4} bytes, COMPLETE lists {size}"]),
                        (no_data, ["data/meta.json is missing", "and "])):
        assert not is_complete(path)
        with pytest.raises(FileNotFoundError) as err:
            load_dataset(path)
        for word in [str(path), "not a complete dataset", "--overwrite", *words]:
            assert word in str(err.value), (word, str(err.value))


def killed_after_first_chunk(out: Path) -> None:
    """Generate ``out`` in a forked process (it shares this one's trajectory tables) and kill it
    with SIGKILL once its first chunk is written."""
    ctx = multiprocessing.get_context("fork")
    written = ctx.Event()

    def generate() -> None:
        def pause(chunk: int) -> None:
            written.set()
            time.sleep(600)

        generate_dataset(out, one_case_spec(), max_batch=3, progress=False, after_chunk=pause)

    proc = ctx.Process(target=generate)
    proc.start()
    try:
        assert written.wait(300), "the generation never wrote a chunk"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.join(60)


def test_a_generation_killed_mid_run_leaves_no_stale_lock_and_resume_keeps_its_flights(tmp_path):
    out = tmp_path / "flights"
    killed_after_first_chunk(out)
    partial = generate_mod.partial_dir(out.resolve())
    assert not out.exists() and lock_path(out).exists()  # a stale file, not a stale lock
    flown = json.loads((partial / generate_mod.PROGRESS_FILE).read_text())["flown"]
    assert flown == [0, 1, 2]
    kept = TensorDict.load_memmap(partial / "data")[torch.tensor(flown)].to_tensordict()
    chunks = []
    generate_dataset(out, one_case_spec(), max_batch=3, progress=False, resume=True, after_chunk=chunks.append)
    assert len(chunks) == 1  # only the unfinished chunk was flown
    now = load_dataset(out)[0][torch.tensor(flown)]
    for key in kept.keys(True, True):
        torch.testing.assert_close(now[key], kept[key], rtol=0, atol=0, equal_nan=True, msg=str(key))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flights"]


# --- training runs ---------------------------------------------------------------------------

FRAMES = 2 * 16  # per iteration


def tiny_ppo(out: Path, iterations: int, **kw):
    """Hovering on the true wind (no estimator), 2 envs x 16 decisions an iteration, a checkpoint
    every iteration."""
    from quadwind_trl.regimes import regime_config
    from quadwind_trl.rl.config import PPOConfig
    from quadwind_trl.rl.envs import DEFAULT_RANGES, RLEnvSpec
    from quadwind_trl.rl.trainer import PPOTrainer

    spec = RLEnvSpec("horizontal", wind_input="truth", config=replace(regime_config("horizontal"), trajectories=TINY),
                     start="pattern", trajectories=("hover",), ranges=replace(DEFAULT_RANGES["horizontal"], altitude_m=(2.0, 2.0)),
                     compile_step=False)  # fmt: skip
    cfg = PPOConfig(total_frames=iterations * FRAMES, num_envs=2, steps_per_env=16, epochs=1, minibatch=16, hidden=(16, 16),
                    eval_every_frames=0, checkpoint_every_frames=FRAMES)
    return PPOTrainer(spec, cfg, out, progress=False, **kw)


def test_a_second_training_run_on_a_run_directory_is_refused(tmp_path):
    """The issue's second reproduction: the second run, by the recipe or the library, stops
    before it writes anything."""
    out = tmp_path / "run"
    with held_by_another_process(out) as first:
        with pytest.raises(OutputInUse) as refused:
            tiny_ppo(out, 1).train()
        recipe = subprocess.run(
            [sys.executable, str(ROOT / "recipes" / "ppo_horizontal.py"), "--quick", "--untrained-estimator", "--out", str(out),
             "--no-progress"], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
    assert_names_the_holder(str(refused.value), out, first.pid, "training run", "--out")
    assert recipe.returncode != 0 and "done:" not in recipe.stdout
    assert_names_the_holder(recipe.stderr, out, first.pid, "training run")
    assert not out.exists()


class Interrupt(Exception):
    pass


def test_a_resumed_run_logs_each_iteration_once(tmp_path):
    """Interrupted once iteration 2 is logged, before its checkpoint (iteration 1's is the
    latest): the resumed run drops iteration 2's rows and logs iterations 2 and 3 once each."""
    out = tmp_path / "run"

    def stop(metrics: dict) -> None:
        if metrics["frames"] == 2 * FRAMES:
            raise Interrupt

    with pytest.raises(Interrupt):
        tiny_ppo(out, 3, on_iteration=stop).train()
    assert torch.load(out / "checkpoints" / "latest.pt", weights_only=True)["progress"]["frames"] == FRAMES
    logs = sorted((out / "logs" / "ppo" / "scalars" / "train").glob("*.csv"))
    assert len(logs) > 5 and all(log.read_text().count("\n") == 2 for log in logs)
    tiny_ppo(out, 3).train(resume=True)
    for log in logs:
        steps = [int(line.split(",")[0]) for line in log.read_text().splitlines()]
        assert steps == [FRAMES, 2 * FRAMES, 3 * FRAMES], (log.name, steps)


def test_truncated_logs_drop_rows_past_the_checkpoint_and_cut_lines(tmp_path):
    scalars = tmp_path / "scalars"
    (scalars / "train").mkdir(parents=True)
    (scalars / "train" / "loss.csv").write_text("1,0.5\n2,0.4\n3,0.3\n4,0.")  # the last line cut by a kill
    (scalars / "lr.csv").write_text("-1,1.0\n0,0.1\n1,0.2\n")
    truncate_scalar_logs(scalars, lambda name: 2 if name == "train/loss" else 0)
    assert (scalars / "train" / "loss.csv").read_text() == "1,0.5\n2,0.4\n"
    assert (scalars / "lr.csv").read_text() == "-1,1.0\n0,0.1\n"
