#!/usr/bin/env bash
# Generate a dataset as a Slurm job array: one shard per array task, then merge.
#   sbatch scripts/slurm_generate.sh            (16 shards of transfer-hard, 10,000 cases)
#   ground data merge --out runs/hard runs/hard/shard-*/dataset-*-of-16.ltds
# SCENARIO, COUNT, SEED, OUT and GROUND (the binary) override the defaults below;
# scripts/slurm-ci.sh runs this array on a single-node cluster and checks the merge.
# Shards are disjoint and reproducible (index mod N), so a failed task is simply resubmitted:
# it resumes from the records it already wrote.
#SBATCH --job-name=lowthrust-generate
#SBATCH --array=0-15
#SBATCH --cpus-per-task=8
#SBATCH --time=04:00:00
#SBATCH --output=runs/hard/slurm-%A_%a.out
set -euo pipefail
SCENARIO=${SCENARIO:-transfer-hard}
COUNT=${COUNT:-10000}
SEED=${SEED:-1}
OUT=${OUT:-runs/hard}
GROUND=${GROUND:-./target/release/ground}
srun "$GROUND" data generate --scenario "$SCENARIO" --count "$COUNT" --seed "$SEED" \
  --shard "${SLURM_ARRAY_TASK_ID}/${SLURM_ARRAY_TASK_COUNT}" --threads "${SLURM_CPUS_PER_TASK}" \
  --out "$OUT/shard-${SLURM_ARRAY_TASK_ID}"
