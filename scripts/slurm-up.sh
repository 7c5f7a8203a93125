#!/usr/bin/env bash
# Brings up a private single-node Slurm (munge + slurmctld + slurmd, as root, no systemd) whose
# whole state lives in SCRATCH: its own munge key and socket, its own slurm.conf, spool, logs
# and pid files, and its own ports. Nothing under /etc or /run is changed, so it neither needs
# nor disturbs a system Slurm. Used by tests/cluster.rs; the recipe is
# /work/shared/notes/slurm.md (Debian 12's slurm-wlm 22.05 and munge 0.5).
#
#   scripts/slurm-up.sh SCRATCH     # starts the daemons, waits until the node is idle
#   export SLURM_CONF=SCRATCH/slurm.conf; sbatch …; squeue …
#   scripts/slurm-down.sh SCRATCH   # stops exactly the daemons started here (by their pid files)
#
# Exit 0: the node is idle and accepts jobs. Exit 1 with one `slurm-up: …` line on stderr when
# the daemons cannot start here (not root, packages missing, a daemon that dies); whatever was
# started is stopped again.
set -euo pipefail
scratch=${1:?usage: scripts/slurm-up.sh SCRATCH_DIR}
here=$(cd "$(dirname "$0")" && pwd)

fail() {
  echo "slurm-up: $*" >&2
  "$here/slurm-down.sh" "$scratch" >/dev/null 2>&1 || true
  exit 1
}

[ "$(id -u)" = 0 ] || fail "must run as root (slurmd starts jobs as their user; munged runs as munge)"
for exe in /usr/sbin/munged /usr/sbin/slurmctld /usr/sbin/slurmd /usr/bin/sbatch /usr/bin/munge; do
  [ -x "$exe" ] || fail "$exe is missing: install Debian's slurm-wlm and munge (scripts/setup.sh --test does)"
done
id munge >/dev/null 2>&1 || fail "no munge user: install Debian's munge"

mkdir -p "$scratch"
scratch=$(cd "$scratch" && pwd)
# munged (user munge) must reach its directory; the jobs write into SCRATCH as root.
chmod 755 "$scratch"
mkdir -p "$scratch/munge" "$scratch/spool/ctld" "$scratch/spool/d" "$scratch/log"
chown munge:munge "$scratch/munge"
chmod 755 "$scratch/munge"   # munged: the socket's directory must be searchable by all

# munge: a fresh key of our own, owned by munge, never the system's /etc/munge/munge.key.
key="$scratch/munge/munge.key"
if [ ! -f "$key" ]; then
  if [ -x /usr/sbin/mungekey ]; then
    /usr/sbin/mungekey --create --keyfile="$key" >/dev/null 2>&1 || fail "mungekey could not create $key"
  else
    dd if=/dev/urandom of="$key" bs=1 count=1024 status=none
  fi
fi
chown munge:munge "$key"
chmod 600 "$key"
socket="$scratch/munge/munge.socket"
runuser -u munge -- /usr/sbin/munged --socket="$socket" --key-file="$key" \
  --pid-file="$scratch/munge/munged.pid" --log-file="$scratch/munge/munged.log" \
  --seed-file="$scratch/munge/munged.seed" \
  || fail "munged did not start: $(tail -n 3 "$scratch/munge/munged.log" 2>/dev/null | tr '\n' ' ')"
for _ in $(seq 50); do [ -S "$socket" ] && break; sleep 0.1; done
/usr/bin/munge -n -S "$socket" | /usr/bin/unmunge -S "$socket" >/dev/null 2>&1 \
  || fail "munge -n | unmunge failed on $socket"

# Two free TCP ports for slurmctld and slurmd (not the defaults 6817/6818, which a system
# Slurm may hold).
read -r ctld_port d_port < <(python3 - <<'EOF'
import socket
ports = []
sockets = []
for _ in range(2):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    sockets.append(s)
    ports.append(s.getsockname()[1])
print(*ports)
EOF
)

host=$(hostname)
cpus=$(nproc)
# RealMemory no larger than the machine's (MB).
memory=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 512 ))
cat >"$scratch/slurm.conf" <<EOF
ClusterName=mjsafe-test
SlurmctldHost=$host
SlurmctldPort=$ctld_port
SlurmdPort=$d_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$socket
CredType=cred/munge
StateSaveLocation=$scratch/spool/ctld
SlurmdSpoolDir=$scratch/spool/d
SlurmctldLogFile=$scratch/log/slurmctld.log
SlurmdLogFile=$scratch/log/slurmd.log
SlurmctldPidFile=$scratch/slurmctld.pid
SlurmdPidFile=$scratch/slurmd.pid
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
MinJobAge=600
SchedulerType=sched/backfill
NodeName=$host CPUs=$cpus RealMemory=$memory State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$scratch/slurm.conf"

/usr/sbin/slurmctld -f "$SLURM_CONF" -i >/dev/null 2>&1 \
  || fail "slurmctld did not start: $(tail -n 3 "$scratch/log/slurmctld.log" 2>/dev/null | tr '\n' ' ')"
/usr/sbin/slurmd -f "$SLURM_CONF" >/dev/null 2>&1 \
  || fail "slurmd did not start: $(tail -n 3 "$scratch/log/slurmd.log" 2>/dev/null | tr '\n' ' ')"

for _ in $(seq 60); do
  state=$(sinfo -h -N -o '%T' 2>/dev/null | head -n 1 || true)
  [ "$state" = idle ] && { echo "slurm-up: node $host idle ($cpus CPUs), SLURM_CONF=$SLURM_CONF"; exit 0; }
  sleep 0.5
done
fail "the node did not become idle within 30 s (state: ${state:-none}); slurmd log: $(tail -n 3 "$scratch/log/slurmd.log" 2>/dev/null | tr '\n' ' ')"
