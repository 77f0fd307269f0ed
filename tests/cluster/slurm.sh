#!/usr/bin/env bash
# A one-node Slurm cluster on localhost runs a dataset as deploy/slurm/submit.sh submits it (an array of 4
# shards, then the merge job); the result must be byte-identical to one process's. Installs Debian's slurmctld,
# slurmd and munge where missing (root), runs everything from a scratch directory with its own slurm.conf (the
# system's Slurm configuration is not touched), and stops and removes everything it started, pass or fail.
#   CI_SLURM=1 bash .ci/run        # runs it after the tests
#   bash tests/cluster/slurm.sh    # on its own (IRSIM=path/to/irsim, else the debug build)
set -euo pipefail
cd "$(dirname "$0")/../.."
repo=$PWD
timeout_s=${SLURM_TEST_TIMEOUT_S:-900}

log() { printf '== slurm test: %s\n' "$*"; }

missing=()
for cmd in slurmctld slurmd munged sbatch; do
  command -v "$cmd" >/dev/null 2>&1 || missing+=("$cmd")
done
if ((${#missing[@]})); then
  log "installing slurmctld slurmd munge (missing: ${missing[*]})"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends slurmctld slurmd slurm-client munge >/dev/null
fi

irsim=${IRSIM:-}
if [[ -z $irsim ]]; then
  target=${CARGO_TARGET_DIR:-$repo/target}
  cargo build --locked --quiet
  irsim=$target/debug/irsim
fi
irsim=$(realpath "$irsim")

work=$(mktemp -d /tmp/irsim-slurm.XXXXXX)
chmod 755 "$work"
started=()
cleanup() {
  local rc=$?
  if [[ -n ${SLURM_CONF:-} ]]; then
    scancel --quiet --user="$(id -un)" 2>/dev/null || true
  fi
  for pid in "${started[@]}"; do
    kill "$pid" 2>/dev/null || true
  done
  for pid in "${started[@]}"; do
    for _ in $(seq 50); do
      kill -0 "$pid" 2>/dev/null || break
      sleep 0.1
    done
    kill -9 "$pid" 2>/dev/null || true
  done
  if ((rc != 0)); then
    for f in "$work"/log/*.log "$work"/jobs/*.out; do
      [[ -f $f ]] && { echo "--- $f"; tail -20 "$f"; }
    done
  fi
  rm -rf "$work"
  exit "$rc"
}
trap cleanup EXIT

# munge: the system's daemon where one runs, else our own on our own socket
mkdir -p "$work"/{log,state,spool,munge,jobs}
munge_socket=/run/munge/munge.socket.2
if ! munge -n >/dev/null 2>&1 </dev/null; then
  munge_socket=$work/munge/munge.socket
  if [[ ! -f /etc/munge/munge.key ]]; then
    key=$work/munge/munge.key
    dd if=/dev/urandom of="$key" bs=1024 count=1 status=none
  else
    key=/etc/munge/munge.key
  fi
  install -m 0400 "$key" "$work/munge/key"
  chmod 700 "$work/munge"
  munged --force --foreground --key-file="$work/munge/key" --socket="$munge_socket" \
    --pid-file="$work/munge/munged.pid" --seed-file="$work/munge/seed" --log-file="$work/log/munged.log" \
    2>>"$work/log/munged.log" &
  started+=($!)
  for _ in $(seq 50); do
    [[ -S $munge_socket ]] && break
    sleep 0.1
  done
fi

node=$(hostname -s)
port=$((20000 + RANDOM % 20000))
# the jobs ask for memory per CPU (deploy/slurm/irsim-dataset.sbatch): the node offers what the machine has
memory_mb=$(($(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 512))
cat >"$work/slurm.conf" <<CONF
ClusterName=irsimtest
SlurmctldHost=${node}(127.0.0.1)
SlurmctldPort=${port}
SlurmdPort=$((port + 1))
SlurmUser=$(id -un)
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=${munge_socket}
CredType=cred/munge
StateSaveLocation=${work}/state
SlurmdSpoolDir=${work}/spool
SlurmctldPidFile=${work}/slurmctld.pid
SlurmdPidFile=${work}/slurmd.pid
SlurmctldLogFile=${work}/log/slurmctld.log
SlurmdLogFile=${work}/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
MinJobAge=600
NodeName=${node} NodeAddr=127.0.0.1 CPUs=2 RealMemory=${memory_mb} State=UNKNOWN
PartitionName=test Nodes=${node} Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF=$work/slurm.conf
log "starting slurmctld and slurmd (ports ${port}, $((port + 1)))"
slurmctld -D -f "$SLURM_CONF" -i >"$work/log/slurmctld.out" 2>&1 &
started+=($!)
slurmd -D -f "$SLURM_CONF" -N "$node" >"$work/log/slurmd.out" 2>&1 &
started+=($!)
deadline=$((SECONDS + 60))
until sinfo -h -o %T 2>/dev/null | grep -qE '^idle'; do
  if ((SECONDS > deadline)); then
    echo "the node did not come up in 60 s" >&2
    sinfo 2>&1 || true
    exit 1
  fi
  sleep 1
done
log "node ${node} idle"

# the dataset: 8 short sequences on the paper's 256×256 camera
spec=$work/spec.toml
cat >"$spec" <<'SPEC'
name = "slurm_test"
seed = 7
sequences = 8
frames = 4
quality = "draft"
sensors = ["paper_lwir_256"]
targets_per_sequence = [1, 2]
classes = ["small_multirotor", "fixed_wing_uav", "bird"]
trajectories = ["straight", "crossing", "approach", "coordinated_turn", "weave"]
range_m = [300, 1500]
SPEC

log "one process"
"$irsim" dataset "$spec" --out "$work/single" --quiet

log "the array of 4 shards and the merge, submitted by deploy/slurm/submit.sh"
cd "$work/jobs"
read -r array merge < <(IRSIM=$irsim "$repo/deploy/slurm/submit.sh" "$spec" "$work/cluster" 4)
log "array job ${array}, merge job ${merge}"
deadline=$((SECONDS + timeout_s))
while squeue -h -j "${array},${merge}" 2>/dev/null | grep -q .; do
  if ((SECONDS > deadline)); then
    echo "the jobs did not finish in ${timeout_s} s" >&2
    squeue >&2 || true
    exit 1
  fi
  sleep 2
done
state=$(scontrol show job "$merge" | grep -oE 'JobState=[A-Z]+' | head -1)
if [[ $state != JobState=COMPLETED ]]; then
  echo "merge job ${merge}: ${state}" >&2
  exit 1
fi
for i in 1 2 3 4; do
  state=$(scontrol show job "${array}_${i}" | grep -oE 'JobState=[A-Z]+' | head -1)
  [[ $state == JobState=COMPLETED ]] || { echo "shard ${i}: ${state}" >&2; exit 1; }
done

log "comparing the two datasets byte for byte"
diff -r "$work/single" "$work/cluster"
files=$(find "$work/cluster" -type f | wc -l)
(cd "$work/cluster" && sha256sum -c --quiet checksums.sha256)
log "passed: ${files} files identical, checksums verified"
