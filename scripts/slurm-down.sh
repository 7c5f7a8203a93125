#!/usr/bin/env bash
# Stops the private Slurm that scripts/slurm-up.sh SCRATCH started: exactly the processes named
# by its pid files (slurmd, slurmctld, munged), TERM then KILL after 10 s. Idempotent.
set -uo pipefail
scratch=${1:?usage: scripts/slurm-down.sh SCRATCH_DIR}

stop() {
  local pidfile=$1 name=$2 pid
  [ -f "$pidfile" ] || return 0
  pid=$(cat "$pidfile" 2>/dev/null)
  [[ "$pid" =~ ^[0-9]+$ ]] || return 0
  # Only our daemon: the pid must still be that program (a stale pid file may name another).
  [ "$(cat "/proc/$pid/comm" 2>/dev/null)" = "$name" ] || { rm -f "$pidfile"; return 0; }
  kill -TERM "$pid" 2>/dev/null || true
  for _ in $(seq 100); do
    kill -0 "$pid" 2>/dev/null || { rm -f "$pidfile"; return 0; }
    sleep 0.1
  done
  kill -KILL "$pid" 2>/dev/null || true
  rm -f "$pidfile"
}

stop "$scratch/slurmd.pid" slurmd
stop "$scratch/slurmctld.pid" slurmctld
stop "$scratch/munge/munged.pid" munged
