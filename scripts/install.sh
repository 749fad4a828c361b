#!/usr/bin/env bash
# Install quadwind_trl into .venv (editable), with the extras named as arguments:
#   bash scripts/install.sh          # the library alone (what scripts/quickstart.sh needs)
#   bash scripts/install.sh test     # and the test extras (Ray, SB3, the docs builder, pytest)
# pip byte-compiles what it installs one file after another, most of a gigabyte of torch: on a
# 2-core machine 91 s of install became 37 s of copying and 29 s of compiling on both cores.
set -euo pipefail
cd "$(dirname "$0")/.."
extras=""
if [ $# -gt 0 ]; then extras="[$(IFS=,; echo "$*")]"; fi
python3 -m venv .venv
.venv/bin/pip install -q --disable-pip-version-check --no-compile -e ".$extras"
# a few of torch's test helpers are written for a newer Python and do not compile, which pip's own
# compilation passes over as well: compileall's exit status reports them, not the install
.venv/bin/python -m compileall -q -j 0 .venv/lib > /dev/null || true
