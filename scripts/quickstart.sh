#!/usr/bin/env bash
# Install into .venv and run the main job on a small default: every stage of the pipeline
# (datasets -> estimators -> PPO policies -> paired ablation -> report) at toy scale, in a few
# minutes on 2 CPU cores. Arguments go to recipes/reproduce.py (e.g. --full for paper scale).
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/pip install -q --disable-pip-version-check -e '.[test]'
exec .venv/bin/python recipes/reproduce.py "${@:---quick}"
