#!/usr/bin/env bash
# Install quadwind_trl into .venv (editable), with the extras named as arguments:
#   bash scripts/install.sh          # the library alone (what scripts/quickstart.sh needs)
#   bash scripts/install.sh test     # and the test extras (Ray, SB3, the docs builder, pytest)
# pip byte-compiles what it installs one file after another, most of a gigabyte of torch: on a
# 2-core machine 91 s of install became 37 s of copying and 29 s of compiling on both cores.
# The library alone compiles only what it imports (2.5k of the 8.6k files, 12 s of CPU against
# 27 s): the test extras compile everything, which pytest's two workers mostly import.
set -euo pipefail
cd "$(dirname "$0")/.."
extras=""
if [ $# -gt 0 ]; then extras="[$(IFS=,; echo "$*")]"; fi
python3 -m venv .venv
.venv/bin/pip install -q --disable-pip-version-check --no-compile -e ".$extras"
if [ -n "$extras" ]; then
  # a few of torch's test helpers are written for a newer Python and do not compile, which pip's own
  # compilation passes over as well: compileall's exit status reports them, not the install
  .venv/bin/python -m compileall -q -j 0 .venv/lib > /dev/null || true
else
  # one process imports what every recipe imports and writes its bytecode (whatever
  # PYTHONDONTWRITEBYTECODE says): the recipes that start next at once find it compiled
  .venv/bin/python -c "import sys; sys.dont_write_bytecode = False
from quadwind_trl.pipeline.local import PRELOADED
for name in PRELOADED: __import__(name)"
fi
