"""The package's layers import downwards only (docs/architecture.md): envs -> estimator -> transforms
-> rl -> evaluation, with data (datasets) beside the estimator's training. Each check imports every
module of one layer in a fresh interpreter and lists what it pulled in from the layers above."""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# layer -> (its modules, excluding these, must not load these packages)
LAYERS = {
    "envs": ((), ("estimator", "data", "transforms", "rl", "evaluation")),
    "estimator": (("training",), ("data", "transforms", "rl", "evaluation")),
    "transforms": ((), ("data", "rl", "evaluation")),
    "rl": ((), ("data", "evaluation")),
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
