#!/usr/bin/env bash
# Integration test: bring up a real single-node Slurm on localhost, submit a
# small sharded sweep as a job array with a dependent merge job, wait, and
# check the merge equals an unsharded run of the same sweep row for row.
#
#   scripts/slurm/ci-test.sh path/to/chirpmap
#
# Needs root (installs Debian's slurmctld slurmd slurm-client munge if absent).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
chirpmap=$(realpath "${1:?usage: ci-test.sh path/to/chirpmap}")
work=$(mktemp -d /tmp/chirpmap-slurm.XXXXXX)
echo "slurm test in $work"

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null || ! command -v sbatch >/dev/null; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq slurmctld slurmd slurm-client munge >/dev/null
fi

# --- munge ------------------------------------------------------------------
mkdir -p /etc/munge /run/munge /var/lib/munge /var/log/munge
if [ ! -s /etc/munge/munge.key ]; then
  dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2>/dev/null
fi
chown -R munge:munge /etc/munge /run/munge /var/lib/munge /var/log/munge
chmod 0700 /etc/munge /var/lib/munge /var/log/munge
chmod 0400 /etc/munge/munge.key
chmod 0755 /run/munge
munge_pid=/run/munge/munged.pid
if ! { [ -s "$munge_pid" ] && kill -0 "$(cat "$munge_pid")" 2>/dev/null; }; then
  runuser -u munge -- /usr/sbin/munged --pid-file="$munge_pid" --socket=/run/munge/munge.socket.2
fi

# --- slurm ------------------------------------------------------------------
conf=$work/slurm.conf
mkdir -p "$work/state" "$work/spool" "$work/log"
cat >"$conf" <<CONF
ClusterName=chirpmap-ci
SlurmctldHost=localhost
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/log/slurmctld.log
SlurmdLogFile=$work/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
NodeName=localhost NodeAddr=127.0.0.1 CPUs=2 State=UNKNOWN
PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF=$conf

stop_daemons() {
  for pidfile in "$work/slurmd.pid" "$work/slurmctld.pid"; do
    if [ -s "$pidfile" ]; then kill "$(cat "$pidfile")" 2>/dev/null || true; fi
  done
  sleep 1
  if [ -s "$munge_pid" ]; then kill "$(cat "$munge_pid")" 2>/dev/null || true; fi
}
fail() {
  echo "slurm test FAILED: $*" >&2
  for f in "$work"/log/*.log "$work"/out/*.out; do
    [ -f "$f" ] && { echo "--- $f"; tail -n 30 "$f"; } >&2
  done
  exit 1
}
trap stop_daemons EXIT

slurmctld -c -f "$conf"
slurmd -N localhost -f "$conf"
for _ in $(seq 1 60); do
  if sinfo -h -o '%t' 2>/dev/null | grep -qE '^(idle|mix|alloc)'; then break; fi
  sleep 1
done
sinfo -h -o '%t' | grep -qE '^(idle|mix|alloc)' || fail "node never became idle: $(sinfo 2>&1)"

# --- the sweep ----------------------------------------------------------------
sweep=$work/sweep.toml
cat >"$sweep" <<'SWEEP'
name = "slurm-ci"
description = "Tiny sweep for the Slurm integration test."
runs = 3
seed = 11
[base.particles]
per_tick = 360
[[params]]
name = "n_obstacles"
path = "random_obstacles.count"
values = [1, 2]
SWEEP
mkdir -p "$work/out"
CHIRPMAP=$chirpmap "$here/submit.sh" "$sweep" "$work/out" 3 | tee "$work/submit.txt"
ids=$(grep -oE '[0-9]+' "$work/submit.txt" | head -n 1)
deadline=$((SECONDS + 600))
while squeue -h -o '%i' | grep -q .; do
  [ $SECONDS -lt $deadline ] || fail "jobs still queued after 10 minutes: $(squeue)"
  sleep 2
done
[ -f "$work/out/merged/runs.csv" ] || fail "merge job produced no runs.csv (array job $ids)"

"$chirpmap" sweep "$sweep" --out "$work/unsharded" --no-progress
strip() { cut -d, -f1-"$(( $(head -n 1 "$1" | tr ',' '\n' | wc -l) - 1 ))" "$1"; }
if ! diff <(strip "$work/out/merged/runs.csv") <(strip "$work/unsharded/runs.csv"); then
  fail "merged sharded runs differ from the unsharded run"
fi
diff "$work/out/merged/summary.csv" "$work/unsharded/summary.csv" || fail "summaries differ"
echo "slurm test passed: $(($(wc -l <"$work/out/merged/runs.csv") - 1)) runs from 3 array tasks merged and equal to the unsharded sweep"
