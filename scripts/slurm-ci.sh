#!/usr/bin/env bash
# Slurm for real, on one machine: starts a single-node cluster (Debian's slurm-wlm and munge,
# installed if missing; needs root), submits scripts/slurm_generate.sh as a job array, cancels it
# once records are on disk and submits it again (the tasks resume from the records they wrote),
# merges the shards and requires the merge to hold the same trajectories as a single run
# (`ground data compare`); then, with a binary that has the learning commands, solves a relabelling
# round's relabels as an array (`[compute.slurm]`) and requires the bytes of the round solved on
# this machine. The cluster is stopped on exit, however the script ends.
#
#   scripts/slurm-ci.sh    # after `cargo build --release -p lowthrust-ground` (or --no-default-features: no relabel array)
#
# Outputs: target/slurm-ci/ (the array's shards and logs, the merge, the single run).
set -euo pipefail
cd "$(dirname "$0")/.."

GROUND="${GROUND:-${CARGO_TARGET_DIR:-target}/release/ground}"
OUT=target/slurm-ci
# Small and quick, but enough cases per task that the cancel lands while tasks are running.
SCENARIO=transfer-circular COUNT=48 SEED=5 TASKS=4

step() { printf '\n==> %s\n' "$*"; }
die() {
    echo "slurm-ci: FAIL: $*" >&2
    exit 1
}

[ -x "$GROUND" ] || die "$GROUND not built (cargo build --release -p lowthrust-ground)"
[ "$(id -u)" = 0 ] || die "starting slurmctld, slurmd and munged needs root"

step "slurm-wlm and munge"
if ! command -v sbatch >/dev/null 2>&1 || ! command -v munged >/dev/null 2>&1; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
fi

step "a single-node cluster: $(hostname -s), $(nproc) CPUs"
node=$(hostname -s)
# slurmctld must resolve its own host name; a bare container may not list it.
getent hosts "$node" >/dev/null || echo "127.0.0.1 $node" >>/etc/hosts
mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm /run/munge
# Containers have no systemd and no cgroup delegation: Linux process tracking, no task plugin.
cat >/etc/slurm/slurm.conf <<EOF
ClusterName=lowthrust-ci
SlurmctldHost=$node
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SchedulerType=sched/backfill
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
ReturnToService=2
NodeName=$node CPUs=$(nproc) State=UNKNOWN
PartitionName=ci Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
[ -s /etc/munge/munge.key ] || mungekey --create --force
chown -R munge:munge /etc/munge /run/munge
chmod 0700 /etc/munge
stop_cluster() {
    scancel --quiet --user=root 2>/dev/null || true
    pkill -x slurmd 2>/dev/null || true
    pkill -x slurmctld 2>/dev/null || true
    pkill -x munged 2>/dev/null || true
}
trap stop_cluster EXIT
stop_cluster
runuser -u munge -- /usr/sbin/munged
slurmctld
slurmd
for _ in $(seq 60); do
    state=$(sinfo -h -n "$node" -o %T 2>/dev/null || true)
    [ "$state" = idle ] && break
    sleep 1
done
[ "$state" = idle ] || die "the node is '$state', not idle (see /var/log/slurm/)"
sinfo --version
sinfo

rm -rf "$OUT"
mkdir -p "$OUT"
submit() {
    sbatch --parsable "$@" --array=0-$((TASKS - 1)) --cpus-per-task=1 --output="$OUT/slurm-%A_%a.out" \
        --export=ALL,GROUND="$GROUND",SCENARIO=$SCENARIO,COUNT=$COUNT,SEED=$SEED,OUT="$OUT/array" \
        scripts/slurm_generate.sh
}
records() { find "$OUT/array" -name '*.rec' 2>/dev/null | wc -l; }

step "the array, cancelled once records are on disk"
job=$(submit)
for _ in $(seq 600); do
    [ "$(records)" -ge 4 ] && break
    sleep 0.2
done
scancel "$job"
while squeue -h -j "$job" 2>/dev/null | grep -q .; do sleep 0.5; done
written=$(records)
echo "job $job cancelled with $written of $COUNT records written"
[ "$written" -lt "$COUNT" ] || die "the array finished before it was cancelled: nothing to resume"

step "the array again: every task resumes from its records"
job=$(submit --wait)
queued=$(squeue -h -j "$job" 2>/dev/null || true)
[ -z "$queued" ] || die "job $job still queued after --wait"
resumed=$(cat "$OUT"/slurm-"$job"_*.out | awk '/records resumed/ {n += $1} END {print n + 0}')
echo "job $job: $resumed records resumed"
[ "$resumed" -ge 1 ] || die "no task resumed a record (logs: $OUT/slurm-${job}_*.out)"

step "merge, and compare with a single run"
"$GROUND" data merge --out "$OUT/merged" "$OUT"/array/shard-*/dataset-*-of-$TASKS.ltds
"$GROUND" data generate --scenario $SCENARIO --count $COUNT --seed $SEED --out "$OUT/single" >/dev/null
"$GROUND" data compare "$OUT/merged/dataset.ltds" "$OUT/single/dataset.ltds"
echo "slurm-ci: the array's merged shards are the single run's trajectories"

# A relabelling round's solves as an array ([compute.slurm]): needs a binary with the learning
# commands (the default build, PyTorch installed).
if "$GROUND" train dagger --help >/dev/null 2>&1; then
    step "a relabelling round solved as a Slurm array: the same relabels as the round solved here"
    R="$OUT/relabel"
    mkdir -p "$R"
    "$GROUND" data generate --scenario transfer-circular --count 2 --seed 9 --final-eps 0.3 --out "$R/data" >/dev/null
    common='scenario = "transfer-circular"
[sac]
hidden = [32, 32]
batch_size = 32
warmup_steps = 60
[generate]
count = 2
seed = 9
final_eps = 0.3
[pretrain]
dataset = "data"
updates = 40
eval_every = 20
mode = "behaviour-cloning"
records = "all"
[dagger]
rounds = 1
episodes = 3
candidates = 6
fractions = [0.3, 0.6]
updates = 10
score_episodes = 4'
    printf '%s\n' "$common" >"$R/here.toml"
    printf '%s\n[compute.slurm]\ntasks = 3\noptions = ["--cpus-per-task=1"]\n' "$common" >"$R/array.toml"
    for arm in here array; do
        "$GROUND" train pretrain --config "$R/$arm.toml" --out "$R/run-$arm" >/dev/null 2>&1
        "$GROUND" train dagger --config "$R/$arm.toml" --out "$R/run-$arm" >/dev/null 2>&1 ||
            die "the $arm round failed (run it: $GROUND train dagger --config $R/$arm.toml --out $R/run-$arm)"
    done
    cmp "$R/run-here/dagger/relabels-1.ltrl" "$R/run-array/dagger/relabels-1.ltrl" ||
        die "the array's relabels differ from the round solved here"
    echo "slurm-ci: the round's relabels solved by the array are the bytes solved here"
else
    echo "slurm-ci: $GROUND has no learning commands (built without PyTorch): the relabel array is not checked"
fi
