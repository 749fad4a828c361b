#!/usr/bin/env bash
# Install into .venv, then run the main job on a small default: every stage of the pipeline
# (datasets -> estimators -> PPO policies -> paired ablation -> report) retrained at toy scale, in
# a few minutes on 2 CPU cores (two stages at a time: the horizontal and vertical chains), and,
# meanwhile, the shipped wind-aware policy against PD on a few paper-scale episodes
# (recipes/first_flight.py: the real result and its figure, printed last). Arguments go to
# recipes/reproduce.py (e.g. --full for paper scale).
set -euo pipefail
cd "$(dirname "$0")/.."
# the library alone: the main job needs none of the test extras (Ray, the docs builder, SB3,
# pytest), which take a third of the install's time; the test command installs them
bash scripts/install.sh
mkdir -p runs/quick
.venv/bin/python recipes/first_flight.py --out runs/quick/first_flight > runs/quick/first_flight.log 2>&1 &
first_flight=$!
echo "the shipped policy flies against PD beside the pipeline (runs/quick/first_flight.log); its result comes last"
.venv/bin/python recipes/reproduce.py "${@:---quick}"
wait "$first_flight"
echo
grep -v "^flights:" runs/quick/first_flight.log
