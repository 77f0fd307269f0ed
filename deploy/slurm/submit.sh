#!/usr/bin/env bash
# Submits a dataset to Slurm: an array of SHARDS tasks (one shard each) and a merge job that runs when all of
# them succeeded. Prints "ARRAY_JOB_ID MERGE_JOB_ID". Extra sbatch options (partition, account, time) go in
# SBATCH_OPTIONS, e.g. SBATCH_OPTIONS="--partition=cpu --time=02:00:00".
#   deploy/slurm/submit.sh datasets/detection.toml /shared/detection 16
set -euo pipefail
if (($# != 3)); then
  echo "usage: $0 SPEC OUT SHARDS" >&2
  exit 2
fi
spec=$1 out=$2 shards=$3
here=$(cd "$(dirname "$0")" && pwd)
# shellcheck disable=SC2086  # SBATCH_OPTIONS is a list of options
array=$(sbatch --parsable ${SBATCH_OPTIONS:-} --array="1-${shards}" "$here/irsim-dataset.sbatch" shard "$spec" "$out")
array=${array%%;*}
# shellcheck disable=SC2086
merge=$(sbatch --parsable ${SBATCH_OPTIONS:-} --dependency="afterok:${array}" --job-name=irsim-dataset-merge \
  --output="irsim-dataset-merge-%j.out" "$here/irsim-dataset.sbatch" merge "$out")
echo "${array} ${merge%%;*}"
