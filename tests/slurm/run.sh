#!/bin/bash
# A real Slurm test of `stepsim slurm` (docs/cluster.md): installs Debian's
# slurm-wlm and munge, starts munged, slurmctld and slurmd as a one-node
# cluster, submits the generated script for a small config as an array of 4,
# and checks that the run is byte-identical to a one-process run; then
# cancels one shard, shows that --finish refuses, reruns the shard alone and
# finishes: byte-identical again. Stops only the daemons it started (by their
# pid files). Needs root and apt; says so and exits 0 with SKIPPED where apt
# is missing. Called by .ci/run. Usage: tests/slurm/run.sh [path/to/stepsim]
set -euo pipefail
cd "$(dirname "$0")/../.."
start=$(date +%s)
STEPSIM=$(realpath "${1:-target/debug/stepsim}")
[ -x "$STEPSIM" ] || { echo "tests/slurm: build stepsim first (cargo build)"; exit 1; }

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
  if ! command -v apt-get >/dev/null; then
    echo "tests/slurm: SKIPPED: apt-get is not available to install slurm-wlm and munge"
    exit 0
  fi
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
fi

D=$(mktemp -d /tmp/stepsim-slurm.XXXXXX)
MUNGE_PID=/run/munge/munged.pid
started_munge=0
cleanup() {
  for f in "$D/slurmd.pid" "$D/slurmctld.pid"; do
    if [ -s "$f" ]; then kill "$(cat "$f")" 2>/dev/null || true; fi
  done
  if [ "$started_munge" = 1 ] && [ -s "$MUNGE_PID" ]; then
    kill "$(cat "$MUNGE_PID")" 2>/dev/null || true
  fi
  sleep 1
  rm -rf "$D"
}
trap cleanup EXIT

# munge: its key comes with the package; start it unless one already runs.
mkdir -p /run/munge && chown munge:munge /run/munge
if [ ! -S /run/munge/munge.socket.2 ] || ! munge -n >/dev/null 2>&1; then
  runuser -u munge -- /usr/sbin/munged
  started_munge=1
fi

host=$(hostname -s)
mkdir -p "$D/state" "$D/spool"
export SLURM_CONF="$D/slurm.conf"
cat > "$SLURM_CONF" <<CONF
ClusterName=stepsimtest
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
SlurmctldPort=16817
SlurmdPort=16818
StateSaveLocation=$D/state
SlurmdSpoolDir=$D/spool
SlurmctldPidFile=$D/slurmctld.pid
SlurmdPidFile=$D/slurmd.pid
SlurmctldLogFile=$D/slurmctld.log
SlurmdLogFile=$D/slurmd.log
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
MinJobAge=300
NodeName=$host NodeAddr=127.0.0.1 CPUs=2 State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
/usr/sbin/slurmctld -c -f "$SLURM_CONF"
/usr/sbin/slurmd -N "$host" -f "$SLURM_CONF"
for _ in $(seq 60); do
  # (grep without -q reads all its input: with pipefail, a grep that
  # stops early can end the writer with SIGPIPE and the pipeline with 141.)
  sinfo -h -o %T 2>/dev/null | grep idle >/dev/null && break
  sleep 0.5
done
sinfo -h -o %T | grep idle >/dev/null || { echo "tests/slurm: the node did not come up"; tail -20 "$D"/*.log; exit 1; }

# A small config: 2 PSFs x 2 shears x 2 images of 128 x 96 (8 images).
cat > "$D/c.json" <<'JSON'
{
  "run": {"seed": 20061130},
  "image": {"width_px": 128, "height_px": 96, "n_images": 2, "margin_arcsec": 2.0},
  "psfs": [
    {"name": "a", "model": "gaussian", "fwhm_arcsec": 0.9},
    {"name": "b", "model": "moffat", "beta": 3.5, "fwhm_arcsec": 0.85}
  ],
  "shears": [{"g1": 0.0173, "g2": -0.0231}, {"g1": 0.0419, "g2": 0.0067}]
}
JSON
"$STEPSIM" generate --config "$D/c.json" --out "$D/one" --threads 1 2>/dev/null
"$STEPSIM" measure --run "$D/one/public" --out "$D/one-ksb.txt" --threads 1 2>/dev/null

wait_for() { # job ids...: until none is queued or running
  for _ in $(seq 300); do
    [ -z "$(squeue -h -j "$(IFS=,; echo "$*")" 2>/dev/null)" ] && return 0
    sleep 0.5
  done
  echo "tests/slurm: jobs $* did not end"; squeue; exit 1
}
same() { # run directory: public/, private/ (no PSFs, markers) and submission as the one-process run
  diff -r "$D/one/public" "$1/public"
  for f in config.json datasets.json blinding.key; do cmp "$D/one/private/$f" "$1/private/$f"; done
  diff -r "$D/one/private/truth" "$1/private/truth"
  diff -r "$D/one/private/done" "$1/private/done"
}

# 1. The whole chain: 4 generate shards, finish, 4 measure shards, finish, score.
"$STEPSIM" slurm --config "$D/c.json" --out "$D/run" --shards 4 --cpus-per-task 1 --stepsim "$STEPSIM" > "$D/submit.sh"
out=$(bash "$D/submit.sh")
echo "$out"
# The first line's job ids (no `head`: it may stop reading before echo has
# written, and pipefail then ends the script with 141).
ids=$(grep -o '[0-9]\+' <<< "${out%%$'\n'*}" | tr '\n' ' ')
# shellcheck disable=SC2086
wait_for $ids
same "$D/run"
cmp "$D/one-ksb.txt" "$D/run-ksb.txt"
[ -f "$D/run-report/report.json" ] || { echo "tests/slurm: no score report"; cat "$D"/run-logs/score-*.out; exit 1; }
ls "$D/run/private/shards"
echo "tests/slurm: chain of 4 shards: byte-identical to one process"

# 2. Cancel shard 3 while the array runs; --finish refuses; rerun shard 3; finish.
gen=$(sbatch --parsable --array=1-4 --output="$D/g-%A_%a.out" \
  --wrap="'$STEPSIM' generate --config '$D/c.json' --out '$D/cut' --shard auto --threads 1")
gen=${gen%%;*}
scancel "${gen}_3"
wait_for "$gen"
if "$STEPSIM" generate --config "$D/c.json" --out "$D/cut" --finish 2> "$D/refused.txt"; then
  echo "tests/slurm: --finish did not refuse a run with a cancelled shard"; exit 1
fi
grep -q "rerun shard 3/4" "$D/refused.txt" || { cat "$D/refused.txt"; exit 1; }
[ ! -e "$D/cut/public/manifest.json" ] || { echo "tests/slurm: a manifest was written"; exit 1; }
echo "tests/slurm: --finish refused: $(grep -c 'missing or unverified' "$D/refused.txt") images missing"
again=$(sbatch --parsable --output="$D/again-%j.out" \
  --wrap="'$STEPSIM' generate --config '$D/c.json' --out '$D/cut' --shard 3/4 --threads 1")
again=${again%%;*}
fin=$(sbatch --parsable --dependency=afterok:"$again" --output="$D/fin-%j.out" \
  --wrap="'$STEPSIM' generate --config '$D/c.json' --out '$D/cut' --finish")
fin=${fin%%;*}
wait_for "$again" "$fin"
same "$D/cut"
echo "tests/slurm: cancelled shard rerun alone and finished: byte-identical to one process"
echo "tests/slurm: passed in $(( $(date +%s) - start )) s"
