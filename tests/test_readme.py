"""Every ```python block of README.md runs as written, alone, in a fresh interpreter (shrunk only
by ``QUADWIND_SNIPPET_EPISODES``, which the snippets read for their batch size)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SNIPPETS = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.DOTALL)


def test_readme_has_snippets():
    assert len(SNIPPETS) >= 4


@pytest.mark.parametrize("code", SNIPPETS, ids=[f"snippet{i}" for i in range(len(SNIPPETS))])
def test_readme_snippet_runs_alone(code, tmp_path):
    env = {**os.environ, "QUADWIND_SNIPPET_EPISODES": "2", "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    # from an empty directory: a snippet may not lean on files beside it
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, f"snippet failed:\n{code}\n{out.stderr[-3000:]}"
