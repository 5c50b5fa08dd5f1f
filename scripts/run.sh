#!/usr/bin/env bash
# The main job (README's first command): installs PyTorch for tch once, builds, and runs
# `ground run` (dataset -> pretraining -> RL -> relabelling rounds -> Monte Carlo -> export, SIL ->
# runs/quick/report.md and runs/quick/model/).
# Extra arguments go to `ground run` (e.g. --config configs/quick.toml --out runs/other).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup-torch.sh
exec cargo run --release -p lowthrust-ground -- run "$@"
