#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for testing sweeps with hydra/launcher=slurm (as root).
#
#   scripts/slurm_cluster.sh [start]   install slurm-wlm and munge if missing (apt-get), write /etc/slurm/slurm.conf
#                                      for this host (its CPU count and memory, as slurmd -C reports them), start
#                                      munged, slurmctld and slurmd, and wait until sinfo shows the node idle
#   scripts/slurm_cluster.sh stop      stop the three daemons
#   scripts/slurm_cluster.sh status    exit 0 when the node is up (idle, mixed or allocated), else 1
#
# Idempotent: a cluster already up is left as it is; a stopped one is started again. Needs root (and apt-get for
# the install); it says so and exits 2 otherwise. Logs: /var/log/slurm/.
set -euo pipefail

CONF=/etc/slurm/slurm.conf
WAIT_S=${SLURM_CLUSTER_WAIT_S:-60}

say() { echo "slurm_cluster: $*" >&2; }

node_up() {
  command -v sinfo >/dev/null 2>&1 || return 1
  local state
  state=$(timeout 10 sinfo -h -N -o %t 2>/dev/null | head -n 1) || return 1
  [[ "$state" == idle* || "$state" == mix* || "$state" == alloc* ]]
}

need_root() {
  if [[ $(id -u) -ne 0 ]]; then
    say "needs root (it installs packages and starts system daemons); run it with sudo"
    exit 2
  fi
}

install() {
  if command -v slurmctld >/dev/null 2>&1 && command -v slurmd >/dev/null 2>&1 && command -v munged >/dev/null 2>&1; then
    return
  fi
  if ! command -v apt-get >/dev/null 2>&1; then
    say "slurm-wlm and munge are missing and there is no apt-get to install them"
    exit 2
  fi
  say "installing slurm-wlm and munge"
  apt-get update -q >/dev/null
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends slurm-wlm munge >/dev/null
}

write_conf() {
  local host cpus memory
  host=$(hostname -s)
  cpus=$(slurmd -C | sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' | head -n 1)
  memory=$(slurmd -C | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' | head -n 1)
  mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
  local new
  new=$(cat <<EOF
# Written by hbni-pyro's scripts/slurm_cluster.sh: one node, this host ($cpus CPUs, $memory MB).
ClusterName=hbni
SlurmctldHost=$host
SlurmUser=root
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
NodeName=$host CPUs=$cpus RealMemory=$memory State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
)
  if [[ ! -f $CONF ]] || [[ "$(cat "$CONF")" != "$new" ]]; then
    printf '%s\n' "$new" >"$CONF"
  fi
}

running() { [[ -f $1 ]] && kill -0 "$(cat "$1")" 2>/dev/null; }

start() {
  if node_up; then
    say "the node is up"
    return
  fi
  need_root
  install
  write_conf
  if [[ ! -s /etc/munge/munge.key ]]; then
    /usr/sbin/mungekey --create >/dev/null 2>&1 || dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 2>/dev/null
    chown munge:munge /etc/munge/munge.key
    chmod 400 /etc/munge/munge.key
  fi
  mkdir -p /run/munge /var/log/munge /var/lib/munge
  chown munge:munge /run/munge /var/log/munge /var/lib/munge
  running /run/munge/munged.pid || runuser -u munge -- /usr/sbin/munged
  running /run/slurmctld.pid || slurmctld
  running /run/slurmd.pid || slurmd
  local waited=0
  until node_up; do
    if ((waited >= WAIT_S)); then
      say "the node is not idle after ${WAIT_S} s: $(sinfo -h -N -o '%t %E' 2>&1 | head -n 1); see /var/log/slurm/"
      exit 1
    fi
    if ((waited == 5)); then  # a node left down by an earlier run comes back on its own only with ReturnToService
      scontrol update nodename="$(hostname -s)" state=resume >/dev/null 2>&1 || true
    fi
    sleep 1
    waited=$((waited + 1))
  done
  say "the node $(hostname -s) is up after ${waited} s"
}

stop() {
  need_root
  for pidfile in /run/slurmd.pid /run/slurmctld.pid /run/munge/munged.pid; do
    if running "$pidfile"; then
      kill "$(cat "$pidfile")"
    fi
  done
  say "stopped"
}

case "${1:-start}" in
  start) start ;;
  stop) stop ;;
  status) node_up ;;
  *) say "usage: $0 [start|stop|status]"; exit 2 ;;
esac
