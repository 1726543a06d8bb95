#!/usr/bin/env bash
# A throwaway single-node Slurm with accounting (munge, MariaDB, slurmdbd, slurmctld, slurmd) for
# `make cluster-test` (docs/how-to/slurm.md). Every file it writes lives in one state directory; every
# daemon it starts is stopped again by the PID it wrote there. Beyond what the apt packages install,
# nothing outside the state directory is written (no file under /etc, no system service started).
#
#   slurm.sh install [RECORD]   apt packages (once); newly installed package names appended to RECORD
#   slurm.sh installable        exit 0 when the packages are installed or apt-get can install them
#   slurm.sh start STATE        configure and start the daemons under STATE (a new, empty directory)
#   slurm.sh stop STATE         cancel our jobs, stop every daemon started under STATE, by PID
#   slurm.sh purge RECORD       apt-get purge the packages RECORD lists (what `install` added)
#
# Clients find this cluster through SLURM_CONF=STATE/etc/slurm.conf and the srun in STATE/bin:
# `eval "$(slurm.sh start STATE)"` sets both.
set -euo pipefail

PACKAGES=(slurm-wlm slurmdbd munge mariadb-server mariadb-client)
# Ports away from the defaults (6817-6819, 3306) so a real Slurm or MySQL on the machine is never met.
CTLD_PORT=${THREEDCAL_SLURMCTLD_PORT:-16817}
SLURMD_PORT=${THREEDCAL_SLURMD_PORT:-16818}
DBD_PORT=${THREEDCAL_SLURMDBD_PORT:-16819}
DB_PORT=${THREEDCAL_MARIADB_PORT:-13306}
CLUSTER=threedcal
ACCOUNT=threedcal

say() { echo "[slurm] $*" >&2; }
die() { echo "[slurm] ERROR: $*" >&2; exit 1; }

missing_packages() {
  local p
  for p in "${PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}\n' "$p" 2>/dev/null | grep -q "install ok installed" || echo "$p"
  done
}

cmd_installable() {
  [ -z "$(missing_packages)" ] && return 0
  local simulate=(apt-get install -s -q --no-install-recommends "${PACKAGES[@]}")
  "${simulate[@]}" >/dev/null 2>&1 && return 0
  apt-get update -q >/dev/null 2>&1 && "${simulate[@]}" >/dev/null 2>&1
}

cmd_install() {
  local record=${1:-}
  [ "$(id -u)" -eq 0 ] || die "installing needs root (apt-get)"
  command -v apt-get >/dev/null || die "apt-get not found (Debian/Ubuntu only)"
  local missing
  missing=$(missing_packages)
  if [ -z "$missing" ]; then
    say "apt packages already installed: ${PACKAGES[*]}"
    return
  fi
  local before after guard=""
  before=$(mktemp)
  after=$(mktemp)
  dpkg-query -W -f='${Package}\n' | sort >"$before"
  # Package scripts must not start system services (we start our own daemons by hand): a
  # policy-rc.d that refuses every start, ours only while apt runs, unless one is already there.
  if [ ! -e /usr/sbin/policy-rc.d ]; then
    guard=/usr/sbin/policy-rc.d
    printf '#!/bin/sh\nexit 101\n' >"$guard"
    chmod 755 "$guard"
  fi
  say "apt-get install ${PACKAGES[*]}"
  local rc=0 log
  log=$(mktemp)
  export DEBIAN_FRONTEND=noninteractive
  apt-get install -y -q --no-install-recommends "${PACKAGES[@]}" >"$log" 2>&1 || {
    say "apt-get install failed; apt-get update and retry"
    apt-get update -q >>"$log" 2>&1 &&
      apt-get install -y -q --no-install-recommends "${PACKAGES[@]}" >>"$log" 2>&1
  } || rc=$?
  [ -n "$guard" ] && rm -f "$guard"
  [ "$rc" -eq 0 ] || { tail -20 "$log" >&2; rm -f "$log"; die "apt-get install ${PACKAGES[*]} failed"; }
  rm -f "$log"
  dpkg-query -W -f='${Package}\n' | sort >"$after"
  local added
  added=$(comm -13 "$before" "$after" | tr '\n' ' ')
  rm -f "$before" "$after"
  say "installed: $added"
  if [ -n "$record" ]; then
    mkdir -p "$(dirname "$record")"
    comm -13 <(sort -u "$record" 2>/dev/null || true) <(tr ' ' '\n' <<<"$added" | sed '/^$/d' | sort -u) >>"$record"
  fi
}

cmd_purge() {
  local record=${1:?usage: slurm.sh purge RECORD}
  [ -s "$record" ] || { say "nothing recorded in $record"; return; }
  # shellcheck disable=SC2046
  DEBIAN_FRONTEND=noninteractive apt-get purge -y -q $(cat "$record") >/dev/null
  rm -f "$record"
  say "purged the packages recorded in $record"
}

port_busy() { (exec 3<>"/dev/tcp/127.0.0.1/$1") 2>/dev/null; }

wait_for() { # wait_for SECONDS WHAT COMMAND...
  local seconds=$1 what=$2
  shift 2
  local i
  for ((i = 0; i < seconds * 5; i++)); do
    "$@" >/dev/null 2>&1 && return 0
    sleep 0.2
  done
  die "$what did not come up within ${seconds}s"
}

cmd_start() {
  local S=${1:?usage: slurm.sh start STATE}
  [ "$(id -u)" -eq 0 ] || die "starting Slurm needs root (slurmd runs jobs as their user)"
  [ -d "$S" ] && [ -z "$(ls -A "$S")" ] || die "$S: must be an existing, empty directory"
  local p
  for p in "$CTLD_PORT" "$SLURMD_PORT" "$DBD_PORT" "$DB_PORT"; do
    port_busy "$p" && die "port $p is in use (set THREEDCAL_SLURM*_PORT / THREEDCAL_MARIADB_PORT)"
  done
  S=$(cd "$S" && pwd)
  chmod 711 "$S" # munged wants its socket reachable by every user (o+x on the path)
  mkdir -p "$S"/{etc,log,munge,mysql,slurmctld,slurmd}
  local host user
  host=$(hostname -s)
  user=$(id -un)

  # munge: its own key and socket.
  dd if=/dev/urandom of="$S/munge/munge.key" bs=1024 count=1 status=none
  chmod 400 "$S/munge/munge.key"
  munged --key-file="$S/munge/munge.key" --socket="$S/munge/munge.socket" \
    --pid-file="$S/munge/munged.pid" --log-file="$S/log/munged.log" --seed-file="$S/munge/munged.seed"
  say "munged pid $(cat "$S/munge/munged.pid")"

  # MariaDB: a private data directory, TCP on 127.0.0.1 only, a password user for slurmdbd.
  mariadb-install-db --no-defaults --datadir="$S/mysql/data" --user="$user" \
    --auth-root-authentication-method=socket --skip-test-db >"$S/log/mariadb-install.log" 2>&1 ||
    die "mariadb-install-db failed (see $S/log/mariadb-install.log)"
  setsid mariadbd --no-defaults --datadir="$S/mysql/data" --socket="$S/mysql/mysqld.sock" \
    --port="$DB_PORT" --bind-address=127.0.0.1 --pid-file="$S/mysql/mariadbd.pid" --user="$user" \
    --log-error="$S/log/mariadb.log" --innodb-buffer-pool-size=64M </dev/null >/dev/null 2>&1 &
  wait_for 60 MariaDB mariadb --no-defaults -S "$S/mysql/mysqld.sock" -u root -e "SELECT 1"
  say "mariadbd pid $(cat "$S/mysql/mariadbd.pid")"
  local dbpass
  dbpass=$(head -c 18 /dev/urandom | base64 | tr -dc 'A-Za-z0-9')
  mariadb --no-defaults -S "$S/mysql/mysqld.sock" -u root -e "
    CREATE DATABASE slurm_acct_db;
    CREATE USER 'slurm'@'127.0.0.1' IDENTIFIED BY '$dbpass';
    GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';"

  # slurmdbd (accounting: the executor plugin asks sacct for job states).
  cat >"$S/etc/slurmdbd.conf" <<EOF
AuthType=auth/munge
AuthInfo=socket=$S/munge/munge.socket
DbdHost=$host
DbdAddr=127.0.0.1
DbdPort=$DBD_PORT
SlurmUser=$user
PidFile=$S/slurmdbd.pid
LogFile=$S/log/slurmdbd.log
StorageType=accounting_storage/mysql
StorageHost=127.0.0.1
StoragePort=$DB_PORT
StorageUser=slurm
StoragePass=$dbpass
StorageLoc=slurm_acct_db
EOF
  chmod 600 "$S/etc/slurmdbd.conf"

  # slurm.conf: one node as this machine reports itself (slurmd -C), partitions `cpu` (default) and
  # `gpu` as in workflow/profiles/slurm. The node declares one GPU (gres.conf: /dev/null as its device): jobs
  # that ask for it are scheduled as on a GPU site, and run on the CPU since no CUDA device exists.
  local node_line
  node_line=$(slurmd -C | head -1)
  [[ "$node_line" == NodeName=* ]] || die "slurmd -C gave no node line: $node_line"
  node_line=${node_line/NodeName=* CPUs/NodeName=$host CPUs}
  cat >"$S/etc/slurm.conf" <<EOF
ClusterName=$CLUSTER
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$CTLD_PORT
SlurmdPort=$SLURMD_PORT
SlurmUser=$user
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$S/munge/munge.socket
StateSaveLocation=$S/slurmctld
SlurmdSpoolDir=$S/slurmd
SlurmctldPidFile=$S/slurmctld.pid
SlurmdPidFile=$S/slurmd.pid
SlurmctldLogFile=$S/log/slurmctld.log
SlurmdLogFile=$S/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
MpiDefault=none
ReturnToService=2
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherFrequency=task=2
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=127.0.0.1
AccountingStoragePort=$DBD_PORT
# Connections to slurmdbd authenticate through the munge socket named here, not AuthInfo's.
AccountingStoragePass=$S/munge/munge.socket
AccountingStorageTRES=gres/gpu
AccountingStoreFlags=job_comment
GresTypes=gpu
MinJobAge=300
$node_line NodeAddr=127.0.0.1 Gres=gpu:1 State=UNKNOWN
PartitionName=cpu Nodes=$host Default=YES MaxTime=INFINITE State=UP
PartitionName=gpu Nodes=$host MaxTime=INFINITE State=UP
EOF
  echo "NodeName=$host Name=gpu File=/dev/null" >"$S/etc/gres.conf"
  export SLURM_CONF="$S/etc/slurm.conf"
  # Inside a job the plugin starts the rule with `srun` after clearing every SLURM_* variable, so
  # srun would look for /etc/slurm/slurm.conf (a real site's place). This cluster keeps its
  # configuration here instead: an srun first on PATH names it.
  mkdir -p "$S/bin"
  printf '#!/bin/sh\nexport SLURM_CONF=%s\nexec %s "$@"\n' "$SLURM_CONF" "$(command -v srun)" >"$S/bin/srun"
  chmod 755 "$S/bin/srun"

  slurmdbd
  wait_for 60 slurmdbd sacctmgr -n show cluster
  say "slurmdbd pid $(cat "$S/slurmdbd.pid")"
  sacctmgr -i add cluster "$CLUSTER" >/dev/null
  sacctmgr -i add account "$ACCOUNT" Cluster="$CLUSTER" Description="threedcal cluster test" \
    Organization=threedcal >/dev/null
  sacctmgr -i add user "$user" Account="$ACCOUNT" DefaultAccount="$ACCOUNT" >/dev/null

  slurmctld
  wait_for 60 slurmctld scontrol ping
  say "slurmctld pid $(cat "$S/slurmctld.pid")"
  slurmd
  wait_for 60 "slurmd (node idle)" bash -c '[[ "$(sinfo -h -N -o %T | head -1)" == idle* ]]'
  say "slurmd pid $(cat "$S/slurmd.pid"); node $(sinfo -h -N -o '%N %T cpus=%c mem=%mMB gres=%G' | head -1)"
  echo "export SLURM_CONF=$SLURM_CONF PATH=$S/bin:\$PATH"
}

stop_pid() { # stop_pid NAME PIDFILE
  local name=$1 pidfile=$2 pid i
  [ -s "$pidfile" ] || return 0
  pid=$(cat "$pidfile")
  if ! kill -0 "$pid" 2>/dev/null; then
    say "$name (pid $pid) already gone"
    return 0
  fi
  kill -TERM "$pid"
  for ((i = 0; i < 150; i++)); do
    kill -0 "$pid" 2>/dev/null || { say "stopped $name (pid $pid)"; return 0; }
    sleep 0.2
  done
  kill -KILL "$pid" 2>/dev/null || true
  say "killed $name (pid $pid) after 30 s"
}

cmd_stop() {
  local S=${1:?usage: slurm.sh stop STATE}
  [ -d "$S" ] || die "$S: no such state directory"
  S=$(cd "$S" && pwd)
  export SLURM_CONF="$S/etc/slurm.conf"
  if [ -s "$S/slurmctld.pid" ] && kill -0 "$(cat "$S/slurmctld.pid")" 2>/dev/null; then
    scancel --user="$(id -un)" 2>/dev/null || true
  fi
  stop_pid slurmd "$S/slurmd.pid"
  stop_pid slurmctld "$S/slurmctld.pid"
  stop_pid slurmdbd "$S/slurmdbd.pid"
  stop_pid mariadbd "$S/mysql/mariadbd.pid"
  stop_pid munged "$S/munge/munged.pid"
  # Job steps (slurmstepd) end with their jobs; report any process still running from STATE.
  # (This script and its callers name STATE on their command lines: they are left out.)
  local proc cmd left="" callers=" " pid=$$
  while [ "$pid" -gt 1 ]; do
    callers+="$pid "
    pid=$(awk '/^PPid:/ {print $2}' "/proc/$pid/status")
  done
  for proc in /proc/[0-9]*; do
    [[ "$callers" == *" ${proc#/proc/} "* ]] && continue
    cmd=$({ tr '\0' ' ' <"$proc/cmdline"; } 2>/dev/null) || continue
    [[ "$cmd" == *"$S"* ]] && left+=" ${proc#/proc/}"
  done
  [ -z "$left" ] || say "WARNING: processes still referring to $S:$left"
}

case "${1:-}" in
  install) cmd_install "${2:-}" ;;
  installable) cmd_installable ;;
  purge) cmd_purge "${2:-}" ;;
  start) cmd_start "${2:-}" ;;
  stop) cmd_stop "${2:-}" ;;
  *) die "usage: slurm.sh install [RECORD] | installable | start STATE | stop STATE | purge RECORD" ;;
esac
