"""The pipeline's stages as Ray tasks (``recipes/reproduce.py --executor ray``), on one local Ray
instance of 2 CPUs shared by the module: stages wait for what they read, skip what is done and
record where they ran; a stage whose worker is killed is retried and resumes; the toy pipeline's
outputs match the local executor's bit for bit; a missing Ray or an unreachable ``--address``
stops the command with a message naming the option."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from functools import partial
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

from quadwind_trl.pipeline import Stage  # noqa: E402
from quadwind_trl.pipeline.local import run_stages_locally  # noqa: E402
from quadwind_trl.pipeline.ray_executor import RayUnavailable, connect, run_stages_on_ray  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=True)
    yield
    ray.shutdown()


# a stage that takes ``seconds`` and records when it ran; with a checkpoint path, its first
# attempt writes the checkpoint and kills the Ray worker running it, and the retry resumes
_STAMP = """import json, os, signal, sys, time
name, seconds, out, checkpoint = sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4:]
t0 = time.time()
print(f"{name} starts")
resumed = bool(checkpoint) and os.path.exists(checkpoint[0])
if checkpoint and not resumed:
    open(checkpoint[0], "w").write("half done")
    os.kill(os.getppid(), signal.SIGKILL)  # the Ray worker
    time.sleep(60)  # killed with it
time.sleep(seconds)
if name.startswith("fail"):
    sys.exit(3)
open(out, "w").write(json.dumps({"start": t0, "end": time.time(), "resumed": resumed, "omp": os.environ.get("OMP_NUM_THREADS")}))
"""


def _stamp(folder: Path, name: str, seconds: float, needs, *extra: str) -> Stage:
    return Stage(name, ("stamp.py", name, str(seconds), str(folder / f"{name}.json"), *extra), folder / f"{name}.json",
                 needs=needs)


def _command(folder: Path, stage: Stage) -> list[str]:
    return [str(folder / stage.args[0]), *stage.args[1:]]


def _span(folder: Path, name: str) -> tuple[float, float]:
    d = json.loads((folder / f"{name}.json").read_text())
    return d["start"], d["end"]


def test_stages_run_as_ray_tasks_once_what_they_read_is_done(local_ray, tmp_path, capsys):
    (tmp_path / "stamp.py").write_text(_STAMP)
    plan = [_stamp(tmp_path, "a", 1.0, ()), _stamp(tmp_path, "b", 1.0, ()), _stamp(tmp_path, "c", 0.2, ("a",)),
            _stamp(tmp_path, "d", 0.1, None)]
    times = tmp_path / "pipeline_times.json"
    run_stages_on_ray(plan, plan, [], times, partial(_command, tmp_path), tmp_path)
    a, b, c, d = (_span(tmp_path, n) for n in "abcd")
    assert a[0] < b[1] and b[0] < a[1]  # two CPUs: a and b at once
    assert c[0] >= a[1] and d[0] >= max(a[1], b[1], c[1])
    # the recipe sees this process's kernel settings, not the OMP_NUM_THREADS Ray gives its workers
    assert json.loads((tmp_path / "a.json").read_text())["omp"] == os.environ.get("OMP_NUM_THREADS")
    record = json.loads(times.read_text())
    assert set(record) == set("abcd")
    assert all(r["ray_node"] == ray.get_runtime_context().get_node_id()[:12] and r["node"] and r["peak_rss_mib"] > 0
               for r in record.values())
    # a rerun skips what is done and runs the forced stage and, after it, what runs in this process
    ran = []
    shipped = Stage("ship", (), tmp_path / "shipped", after=lambda: ran.append(_span(tmp_path, "d")))
    capsys.readouterr()
    run_stages_on_ray([*plan, shipped], [*plan, shipped], ["d"], times, partial(_command, tmp_path), tmp_path)
    out = capsys.readouterr().out
    assert all(f"[{n}] done already" in out for n in "abc")
    assert ran == [_span(tmp_path, "d")] and _span(tmp_path, "d")[0] > d[1]


def test_a_stage_whose_worker_is_killed_is_retried_and_resumes(local_ray, tmp_path):
    (tmp_path / "stamp.py").write_text(_STAMP)
    plan = [_stamp(tmp_path, "killed", 0.1, (), str(tmp_path / "checkpoint"))]
    run_stages_on_ray(plan, plan, [], tmp_path / "pipeline_times.json", partial(_command, tmp_path), tmp_path)
    assert (tmp_path / "checkpoint").read_text() == "half done"
    assert json.loads((tmp_path / "killed.json").read_text())["resumed"]


def test_a_failed_stage_hands_nothing_more_to_ray(local_ray, tmp_path, capsys):
    (tmp_path / "stamp.py").write_text(_STAMP)
    plan = [_stamp(tmp_path, "fail", 0.1, ()), _stamp(tmp_path, "after", 0.1, ("fail",))]
    with pytest.raises(SystemExit, match="stage fail failed; 1 stage did not start"):
        run_stages_on_ray(plan, plan, [], tmp_path / "pipeline_times.json", partial(_command, tmp_path), tmp_path)
    assert "[fail] failed (exit status 3)" in capsys.readouterr().out
    assert not (tmp_path / "after.json").exists()


def _reproduce(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "recipes" / "reproduce.py"), *args], cwd=ROOT, capture_output=True,
                          text=True, env=env or ENV, timeout=600)


def test_an_unreachable_or_malformed_address_is_refused_naming_the_option(tmp_path):
    run = _reproduce("--quick", "--out", str(tmp_path / "q"), "--executor", "ray", "--address", "127.0.0.1:1")
    assert run.returncode == 2 and "--address 127.0.0.1:1: no Ray head node answers there" in run.stderr, run.stderr
    run = _reproduce("--quick", "--out", str(tmp_path / "q"), "--address", "auto")
    assert run.returncode == 2 and "--address auto: only with --executor ray" in run.stderr, run.stderr
    with pytest.raises(RayUnavailable, match="--address 'head-node': expected 'auto' or HOST:PORT"):
        connect("head-node", 2)


def test_a_missing_ray_names_the_options(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails as if not installed
    with pytest.raises(RayUnavailable, match=r"--executor ray needs Ray, which is not installed: pip install "
                                             r"'quadwind_trl\[ray\]', or leave out --executor ray and --address"):
        connect(None, 2)


def _load_reproduce(monkeypatch):
    import importlib.util

    spec = importlib.util.spec_from_file_location("reproduce", ROOT / "recipes" / "reproduce.py")
    reproduce = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "reproduce", reproduce)
    spec.loader.exec_module(reproduce)
    return reproduce


@pytest.mark.slow
def test_the_toy_pipelines_first_stages_make_the_same_bits_as_the_local_executor(local_ray, tmp_path, monkeypatch):
    """The toy pipeline's horizontal dataset and estimator, once as Ray tasks and once as local
    processes: every dataset array and every estimator tensor agree to the bit (the whole toy
    pipeline's comparison: docs/scaling.md)."""
    import torch

    reproduce = _load_reproduce(monkeypatch)
    only = ("data-horizontal", "estimator-horizontal")
    runs = {}
    for executor in ("local", "ray"):
        out = tmp_path / executor
        plan = reproduce.stages(True, out)
        selected = [s for s in plan if s.name in only]
        times = out / "pipeline_times.json"
        out.mkdir()
        if executor == "ray":
            run_stages_on_ray(selected, plan, [], times, partial(reproduce.stage_command, force=[]), ROOT)
        else:
            run_stages_locally(selected, plan, [], 2, times, partial(reproduce.stage_command, force=[]), ROOT)
        runs[executor] = out
    data = sorted(p.relative_to(runs["local"]) for p in (runs["local"] / "data").rglob("*.memmap"))
    assert len(data) > 5
    for path in data:
        assert (runs["local"] / path).read_bytes() == (runs["ray"] / path).read_bytes(), path
    local, on_ray = (_tensors(torch.load(runs[e] / "estimator_horizontal.pt", weights_only=False)) for e in ("local", "ray"))
    assert len(local) > 5 and local.keys() == on_ray.keys()
    assert all(torch.equal(local[k], on_ray[k]) for k in local), [k for k in local if not torch.equal(local[k], on_ray[k])]
    # and its manifest names the same platform, so a re-flight of a Ray run is checked bit for bit
    platform = [json.loads((runs[e] / "estimator_horizontal.json").read_text())["platform"] for e in ("local", "ray")]
    assert platform[0] == platform[1]


def _tensors(obj, prefix: str = "") -> dict:
    """Every tensor in a checkpoint's nested dicts and lists, by its path."""
    import torch

    if isinstance(obj, torch.Tensor):
        return {prefix: obj}
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, (list, tuple)) else ()
    return {k: v for key, value in items for k, v in _tensors(value, f"{prefix}/{key}").items()}


def test_a_stage_no_node_can_hold_is_refused_before_anything_runs():
    from quadwind_trl.pipeline import StageResources
    from quadwind_trl.pipeline.ray_executor import check_fits

    nodes = [{"CPU": 2.0, "memory": 8 * 2**30}, {"CPU": 16.0, "GPU": 1.0, "memory": 4 * 2**30}]
    fits = [Stage("a", ("x.py",), Path("a"), resources=StageResources(cpus=16, gpus=1, memory_gib=4)),
            Stage("b", ("x.py",), Path("b"), resources=StageResources(cpus=2, memory_gib=8))]
    check_fits(fits, nodes)
    big = Stage("big", ("x.py",), Path("big"), resources=StageResources(cpus=16, memory_gib=8))
    with pytest.raises(ValueError, match=r"stage big asks for .*\(the largest: 16 CPUs, 1 GPUs, 8.0 GiB"):
        check_fits([*fits, big], nodes)
    with pytest.raises(ValueError, match=r"StageResources.memory_gib=-1: allowed range: a finite number >= 0"):
        StageResources(memory_gib=-1)
