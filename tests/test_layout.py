"""The package's layers import downwards only (docs/architecture.md): envs -> estimator -> transforms
-> rl -> evaluation -> studies, with data (datasets) beside the estimator's training. Each check imports every
module of one layer in a fresh interpreter and lists what it pulled in from the layers above."""
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# layer -> (its modules, excluding these, must not load these packages)
LAYERS = {
    "envs": ((), ("estimator", "data", "transforms", "rl", "evaluation", "studies")),
    "estimator": (("training",), ("data", "transforms", "rl", "evaluation", "studies")),
    "transforms": ((), ("data", "rl", "evaluation", "studies")),
    "rl": ((), ("data", "evaluation", "studies")),
    "evaluation": ((), ("studies",)),
}

CODE = """
import importlib, pkgutil, sys
pkg = importlib.import_module("quadwind_trl.{layer}")
for m in pkgutil.walk_packages(pkg.__path__, "quadwind_trl.{layer}."):
    if m.name.rsplit(".", 1)[-1] not in {skip!r}:
        importlib.import_module(m.name)
print(sorted({{n for n in sys.modules for up in {above!r} if n == "quadwind_trl." + up or n.startswith("quadwind_trl." + up + ".")}}))
"""


@pytest.mark.parametrize("layer", list(LAYERS))
def test_a_layer_imports_nothing_above_it(layer):
    skip, above = LAYERS[layer]
    code = CODE.format(layer=layer, skip=skip, above=above)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[]", f"quadwind_trl.{layer} imports from the layers above it: {proc.stdout.strip()}"


def test_validation_imports_nothing_from_the_package():
    """The boundary checks sit below every layer (no import cycle through them): what they check
    against that lives above (the trajectory registry) is handed in by the caller. Function-level
    imports count too."""
    import ast

    tree = ast.parse((ROOT / "quadwind_trl" / "validation.py").read_text())
    own = [ast.unparse(node) for node in ast.walk(tree)
           if (isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("quadwind_trl")))
           or (isinstance(node, ast.Import) and any(a.name.startswith("quadwind_trl") for a in node.names))]
    assert own == [], f"quadwind_trl/validation.py imports from the package: {own}"


# --- paths: every path a manifest, results file or doc records is relative to the repository ----

#: the start of a machine's absolute path (not a URL's path: no word character, dot, slash or colon before it)
MACHINE_PATH = re.compile(r"(?<![\w./:~-])/(?:work|tmp|home|root|Users|mnt|scratch)/")


def _fake_checkout(folder: Path) -> Path:
    """A directory that looks like another checkout (worktree, clone) of this project."""
    (folder / "quadwind_trl").mkdir(parents=True)
    (folder / "quadwind_trl" / "__init__.py").write_text("")
    (folder / "pyproject.toml").write_text('[project]\nname = "quadwind_trl"\n')
    return folder


def test_repo_relative_inside_this_checkout():
    from quadwind_trl.manifest import ROOT, command_line, repo_relative

    assert repo_relative(ROOT / "quadwind_trl" / "checkpoints" / "estimator_horizontal.pt") == "quadwind_trl/checkpoints/estimator_horizontal.pt"
    assert repo_relative(ROOT / "data" / "not_made_yet") == "data/not_made_yet"
    assert repo_relative("data/flights_horizontal") == "data/flights_horizontal"  # relative: unchanged
    assert command_line(["recipes/x.py", "--data", str(ROOT / "data" / "d"), f"--out={ROOT / 'runs' / 'r'}"]) == (
        "python recipes/x.py --data data/d --out=runs/r")


def test_repo_relative_inside_another_checkout(tmp_path):
    """A run in another worktree of the repository (with the package imported from this one)
    records that worktree's paths relative to it."""
    from quadwind_trl.manifest import checkout_root, command_line, repo_relative

    other = _fake_checkout(tmp_path / "wt" / "b")
    (other / "data" / "flights_horizontal").mkdir(parents=True)
    assert checkout_root(other / "data" / "flights_horizontal") == other.resolve()
    assert repo_relative(other / "data" / "flights_horizontal") == "data/flights_horizontal"
    assert repo_relative(str(other / "data" / "flights_horizontal_unseen")) == "data/flights_horizontal_unseen"  # need not exist
    assert repo_relative(other / "quadwind_trl" / "checkpoints" / "estimator_horizontal.pt") == (
        "quadwind_trl/checkpoints/estimator_horizontal.pt")
    assert command_line(["recipes/evaluate_estimator.py", "--data", str(other / "data" / "flights_horizontal")]) == (
        "python recipes/evaluate_estimator.py --data data/flights_horizontal")


def test_repo_relative_outside_any_checkout(tmp_path):
    from quadwind_trl.manifest import checkout_root, command_line, repo_relative

    (tmp_path / "pyproject.toml").write_text("")  # a project, but not this one (no quadwind_trl/__init__.py)
    outside = tmp_path / "scratch" / "data"
    assert checkout_root(outside) is None
    assert repo_relative(outside) == str(outside)
    assert command_line(["recipes/x.py", "--data", str(outside)]) == f"python recipes/x.py --data {outside}"


def _recorded_files() -> list[Path]:
    files = [*(ROOT / "docs").rglob("*.md"), *(ROOT / "results").rglob("*.json"), *(ROOT / "results").rglob("*.md"),
             *(ROOT / "quadwind_trl" / "checkpoints").glob("*.json"), ROOT / "README.md"]
    return sorted(f for f in files if f.is_file())


def test_docs_and_results_name_no_machine_path():
    """Docs, results and the shipped manifests name files relative to the repository: a machine's
    own directories (a scratch worktree, a home or temporary folder) mean nothing on another."""
    found = [f"{path.relative_to(ROOT)}:{n}: {line.strip()[:160]}"
             for path in _recorded_files()
             for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1) if MACHINE_PATH.search(line)]
    assert not found, "absolute paths of a machine (make them relative to the repository):\n" + "\n".join(found)
