#!/usr/bin/env bash
# Install into .venv, fly the shipped wind-aware policy against PD on a few paper-scale episodes
# (recipes/first_flight.py: the real result and its figure, about a minute), then run the main job
# on a small default: every stage of the pipeline (datasets -> estimators -> PPO policies ->
# paired ablation -> report) retrained at toy scale, in a few minutes on 2 CPU cores. Arguments
# go to recipes/reproduce.py (e.g. --full for paper scale).
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
.venv/bin/pip install -q --disable-pip-version-check -e '.[test]'
.venv/bin/python recipes/first_flight.py --out runs/quick/first_flight
echo
exec .venv/bin/python recipes/reproduce.py "${@:---quick}"
