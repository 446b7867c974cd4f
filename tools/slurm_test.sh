#!/usr/bin/env bash
# A real scheduler in a test (issue 27): installs Debian's slurm-wlm and munge if slurmctld is
# missing (apt-get, as root or with sudo), starts a single-node Slurm (slurmctld and slurmd in
# the foreground, no systemd, every file in a temporary folder), submits the README's job array
# scaled down (4 shards of a tiny campaign, docs/campaigns.md "Running on a cluster") and a
# dependent merge job, then runs the same campaign unsharded and compares every file of the
# merged folder with the unsharded one, byte for byte. Exit 0 only if all are identical.
#
# Usage: tools/slurm_test.sh
#   AIFT_BIN=PATH            the aift binary (default target/release/aift; not built here)
#   AIFT_SLURM_TIMEOUT=S     how long the jobs may take together (default 600 s)
#   AIFT_SLURM_KEEP=1        keep the temporary folder (configuration, logs, outputs)
# Run the daemons as root (the usual case in a container); as another user they run as that
# user (SlurmUser = SlurmdUser = you), which Slurm supports only for jobs of that same user.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
export PATH="$PATH:/usr/sbin:/sbin"

aift=$(realpath -m "${AIFT_BIN:-$root/target/release/aift}")
[ -x "$aift" ] || {
  echo "error: no aift binary at $aift (cargo build --release --bin aift, or set AIFT_BIN)" >&2
  exit 1
}
timeout_s=${AIFT_SLURM_TIMEOUT:-600}

sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"

apt_install() {
  echo "== apt-get install $*" >&2
  local log
  log=$(mktemp)
  # apt-get update only if the install fails first (the lists may be current already).
  if ! $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "$@" \
    >"$log" 2>&1; then
    if ! { $sudo env DEBIAN_FRONTEND=noninteractive apt-get update \
      && $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "$@"; } \
      >"$log" 2>&1; then
      tail -n 30 "$log" >&2
      rm -f "$log"
      echo "error: apt-get install $* failed" >&2
      exit 1
    fi
  fi
  rm -f "$log"
}

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
  apt_install slurm-wlm munge
fi
for tool in slurmctld slurmd sbatch squeue sinfo scontrol scancel munged munge unmunge; do
  command -v "$tool" >/dev/null || { echo "error: $tool not found after installing" >&2; exit 1; }
done

# --- the temporary cluster ------------------------------------------------------------------
tmp=$(mktemp -d)
chmod 700 "$tmp"
user=$(id -un)
node=$(hostname -s)
mkdir -p "$tmp"/{etc,state,spool/slurmd-"$node",log,run,munge,work/logs,cache}
munged_pid="" ctld_pid="" slurmd_pid="" jobs=""

stop_pid() { # stop_pid PID: TERM, up to 10 s, then KILL; only processes this script started
  local pid=$1 i
  [ -n "$pid" ] || return 0
  kill "$pid" 2>/dev/null || return 0
  for i in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
  kill -9 "$pid" 2>/dev/null || true
  wait "$pid" 2>/dev/null || true
}

cleanup() {
  local rc=$?
  set +e
  trap - EXIT INT TERM
  if [ -n "$jobs" ] && [ -n "$ctld_pid" ] && kill -0 "$ctld_pid" 2>/dev/null; then
    # Jobs run under slurmstepd, which outlives slurmd: cancel what is left first.
    # shellcheck disable=SC2086
    scancel $jobs 2>/dev/null
    for _ in $(seq 50); do
      [ -z "$(squeue -h -j "${jobs// /,}" -o %i 2>/dev/null)" ] && break
      sleep 0.2
    done
  fi
  stop_pid "$slurmd_pid"
  stop_pid "$ctld_pid"
  stop_pid "$munged_pid"
  if [ "${AIFT_SLURM_KEEP:-}" = 1 ]; then
    echo "kept $tmp" >&2
  else
    rm -rf "$tmp"
  fi
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

die() {
  echo "error: $*" >&2
  exit 1
}

show_logs() { # the daemons' logs, then the jobs' output files
  local f
  for f in "$tmp"/log/*.log "$tmp"/work/logs/*; do
    [ -f "$f" ] || continue
    echo "---- $f (last 25 lines)" >&2
    tail -n 25 "$f" >&2
  done
}

# MUNGE: use a running munged if the default socket works, else start one with a fresh key.
sock=""
if pgrep -x munged >/dev/null && munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  echo "== using the running munged (default socket)"
else
  sock="$tmp/munge/munge.socket"
  # --force: munged refuses a socket whose parent folders others cannot traverse ($tmp is
  # 0700); here only this user (daemons and jobs alike) talks to it.
  dd if=/dev/urandom of="$tmp/munge/munge.key" bs=1024 count=1 status=none
  chmod 400 "$tmp/munge/munge.key"
  munged --foreground --force --key-file="$tmp/munge/munge.key" --socket="$sock" \
    --pid-file="$tmp/munge/munged.pid" --log-file="$tmp/log/munged.log" \
    --seed-file="$tmp/munge/munged.seed" >"$tmp/log/munged.out" 2>&1 &
  munged_pid=$!
  for _ in $(seq 50); do [ -S "$sock" ] && break; sleep 0.2; done
  [ -S "$sock" ] || { show_logs; die "munged did not create its socket $sock"; }
  echo "== started munged (pid $munged_pid, socket $sock)"
fi
munge -n ${sock:+--socket="$sock"} | unmunge ${sock:+--socket="$sock"} >/dev/null \
  || { show_logs; die "munge -n | unmunge failed"; }

port_free() { ! (exec 3<>"/dev/tcp/127.0.0.1/$1") 2>/dev/null; }
free_port() { # the first free port from $1 on
  local p=$1
  while ! port_free "$p"; do p=$((p + 1)); done
  echo "$p"
}
ctld_port=$(free_port 6817)
slurmd_port=$(free_port $((ctld_port + 1)))

cpus=$(nproc)
# The node's memory in MiB, as slurmd counts it, less 5 %: a node configured with more memory
# than slurmd finds is drained ("Low RealMemory").
mem=$(awk '/^MemTotal:/ { printf "%d", $2 / 1024 * 0.95 }' /proc/meminfo)
conf="$tmp/etc/slurm.conf"
: >"$tmp/etc/plugstack.conf" # not the system's /etc/slurm/plugstack.conf
cat >"$conf" <<EOF
ClusterName=aifttest
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmUser=$user
SlurmdUser=$user
AuthType=auth/munge
CredType=cred/munge
${sock:+AuthInfo=socket=$sock}
StateSaveLocation=$tmp/state
SlurmdSpoolDir=$tmp/spool/slurmd-%n
SlurmctldPidFile=$tmp/run/slurmctld.pid
SlurmdPidFile=$tmp/run/slurmd.pid
SlurmctldLogFile=$tmp/log/slurmctld.log
SlurmdLogFile=$tmp/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
PlugStackConfig=$tmp/etc/plugstack.conf
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
MpiDefault=none
MailProg=/bin/true
ReturnToService=2
MinJobAge=3600
DependencyParameters=kill_invalid_depend
NodeName=$node NodeAddr=127.0.0.1 NodeHostname=$node CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$conf"

slurmctld -D -f "$conf" >"$tmp/log/slurmctld.out" 2>&1 &
ctld_pid=$!
slurmd -D -f "$conf" >"$tmp/log/slurmd.out" 2>&1 &
slurmd_pid=$!
echo "== started slurmctld (pid $ctld_pid, port $ctld_port) and slurmd (pid $slurmd_pid, port $slurmd_port) for node $node: $cpus CPUs, $mem MiB"

state=""
for i in $(seq 120); do
  kill -0 "$ctld_pid" 2>/dev/null || { show_logs; die "slurmctld exited"; }
  kill -0 "$slurmd_pid" 2>/dev/null || { show_logs; die "slurmd exited"; }
  state=$(sinfo -h -n "$node" -o %T 2>/dev/null || true)
  [ "$state" = idle ] && break
  case "$state" in drain* | down* | fail*)
    show_logs
    die "node $node is $state: $(scontrol show node "$node" | grep -o 'Reason=.*')" ;;
  esac
  sleep 0.5
done
[ "$state" = idle ] || { show_logs; die "node $node not idle after 60 s (sinfo says '${state:-nothing}')"; }
echo "== node $node idle after $((i / 2)) s"

# --- the campaign and the jobs --------------------------------------------------------------
work="$tmp/work"
campaign_file="$work/slurm-test.toml"
# tests/common/mod.rs's tiny_campaign (paper arm, 2 cells, 2 methods, 9 s articulated runs)
# with a small reaching benchmark, so that reaching.csv is merged too.
cat >"$campaign_file" <<EOF
name = "slurm-test"
seeds = 1
methods = ["no-ft", "oracle"]
defaults = { duration = 9.0, plant = { engine = "articulated" } }
channels = ["enc*"]

[[arms]]
name = "paper"
scenario = "$root/assets/scenarios/paper_healthy.toml"

[[kinds]]
kind = "freeze"
onsets = ["moving"]

[reaching]
tasks = 2
duration = 3.0
EOF
export AIFT_CACHE_DIR="$tmp/cache" # the jobs inherit the environment (sbatch --export=ALL)

q_aift=$(printf %q "$aift")
q_file=$(printf %q "$campaign_file")
# The README's recipe, scaled down from 16 shards of 4 CPUs and 10 seeds.
cat >"$work/shards.sh" <<EOF
#!/bin/bash
#SBATCH --array=0-3
#SBATCH --cpus-per-task=1
#SBATCH --job-name=aift-shards
#SBATCH --output=logs/shard-%A_%a.out
N=4
$q_aift campaign $q_file --seeds 2 \\
    --shard \$((SLURM_ARRAY_TASK_ID+1))/\$N --out shards/\$SLURM_ARRAY_TASK_ID
EOF
cat >"$work/merge.sh" <<EOF
#!/bin/bash
#SBATCH --cpus-per-task=1
#SBATCH --job-name=aift-merge
#SBATCH --output=logs/merge-%j.out
$q_aift merge shards/* --out campaign
EOF

cd "$work"
array_id=$(sbatch --parsable --chdir="$work" shards.sh | cut -d';' -f1)
jobs="$array_id"
merge_id=$(sbatch --parsable --chdir="$work" --dependency=afterok:"$array_id" \
  --kill-on-invalid-dep=yes merge.sh | cut -d';' -f1)
jobs="$array_id $merge_id"
echo "== submitted job array $array_id (4 shards) and merge job $merge_id (afterok:$array_id)"

start=$SECONDS
while [ -n "$(squeue -h -j "$array_id,$merge_id" -o %i)" ]; do
  kill -0 "$ctld_pid" 2>/dev/null || { show_logs; die "slurmctld exited"; }
  kill -0 "$slurmd_pid" 2>/dev/null || { show_logs; die "slurmd exited"; }
  [ $((SECONDS - start)) -lt "$timeout_s" ] || {
    squeue -j "$array_id,$merge_id" >&2
    show_logs
    die "the jobs did not finish in $timeout_s s"
  }
  sleep 1
done
echo "== jobs done after $((SECONDS - start)) s"

states=$(scontrol -o show job "$array_id"; scontrol -o show job "$merge_id")
summary=$(awk '{ s = ""; for (i = 1; i <= NF; i++)
  if ($i ~ /^(JobId|ArrayTaskId|JobName|JobState|Reason|ExitCode)=/) s = s " " $i; print "  " s }' \
  <<<"$states")
if [ "$(grep -c 'JobState=COMPLETED' <<<"$states")" -ne 5 ]; then
  show_logs
  echo "$summary" >&2
  die "a job failed (5 COMPLETED expected: 4 shards and the merge)"
fi
echo "$summary"

# --- the unsharded campaign and the comparison ---------------------------------------------
"$aift" campaign "$campaign_file" --seeds 2 --out whole >"$tmp/log/whole.out" 2>&1 \
  || { cat "$tmp/log/whole.out" >&2; die "the unsharded campaign failed"; }
[ -d campaign ] || { show_logs; die "the merge job wrote no campaign/ folder"; }
(cd campaign && find . -type f -printf "%P\n" | sort) >"$tmp/merged.list"
(cd whole && find . -type f -printf "%P\n" | sort) >"$tmp/whole.list"
diff "$tmp/whole.list" "$tmp/merged.list" >&2 \
  || die "campaign/ (merged, >) and whole/ (<) hold different files"
for f in campaign.json campaign.csv records.json report.html; do
  grep -qx "$f" "$tmp/whole.list" || die "whole/ has no $f"
done
n=0
bad=0
while read -r f; do
  n=$((n + 1))
  cmp "whole/$f" "campaign/$f" >&2 || bad=1
done <"$tmp/whole.list"
[ "$bad" = 0 ] || die "merged and unsharded campaigns differ"
echo "   $(tr '\n' ' ' <"$tmp/whole.list")"
echo "slurm test passed: $n files identical (${SECONDS} s in all)"
