"""Every ```python block of README.md and of the documentation pages that teach the API
(getting started, extending) runs as written, alone, in a fresh interpreter (shrunk only by
``QUADWIND_SNIPPET_EPISODES``, which the snippets read for their batch size). A block that appears
on two pages runs once."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = ("README.md", "docs/getting-started.md", "docs/extending.md")


def _blocks(page: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / page).read_text(), flags=re.DOTALL)


#: (page, index on the page) -> code, each distinct block once, at its first page
SNIPPETS: dict[str, str] = {}
for _page in PAGES:
    for _i, _code in enumerate(_blocks(_page)):
        if _code not in SNIPPETS.values():
            SNIPPETS[f"{_page}:{_i}"] = _code


def test_readme_has_snippets():
    # the README: one TorchRL example and one gymnasium example
    readme = _blocks("README.md")
    assert len(readme) >= 2
    assert any("QuadWindEnv" in code for code in readme) and any("gymnasium" in code for code in readme)
    # with the guide: the env, a PD flight, the estimator transform, gymnasium, a trajectory, a controller
    assert len(SNIPPETS) >= 6, list(SNIPPETS)


@pytest.mark.parametrize("code", list(SNIPPETS.values()), ids=list(SNIPPETS))
def test_readme_snippet_runs_alone(code, tmp_path):
    env = {**os.environ, "QUADWIND_SNIPPET_EPISODES": "2", "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    # from an empty directory: a snippet may not lean on files beside it
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, f"snippet failed:\n{code}\n{out.stderr[-3000:]}"
