#!/usr/bin/env bash
# Submit a sharded sweep as a job array plus a merge job that runs when every
# shard succeeded. Prints the two job ids.
#
#   scripts/slurm/submit.sh SWEEP OUT SHARDS [chirpmap sweep flags...]
#   scripts/slurm/submit.sh table1 /scratch/me/table1 16
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
sweep=${1:?usage: submit.sh SWEEP OUT SHARDS [flags]}
out=${2:?usage: submit.sh SWEEP OUT SHARDS [flags]}
shards=${3:?usage: submit.sh SWEEP OUT SHARDS [flags]}
shift 3
mkdir -p "$out"
# Jobs run with --chdir=OUT, so make paths absolute.
out=$(realpath "$out")
if [ -f "$sweep" ]; then sweep=$(realpath "$sweep"); fi
array_id=$(sbatch --parsable --array="0-$((shards - 1))" --chdir="$out" "$here/sweep-array.sbatch" "$sweep" "$out" "$@")
array_id=${array_id%%;*}
merge_id=$(sbatch --parsable --dependency="afterok:$array_id" --chdir="$out" "$here/merge.sbatch" "$out")
merge_id=${merge_id%%;*}
echo "array job $array_id ($shards shards), merge job $merge_id -> $out/merged"
