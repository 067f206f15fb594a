#!/usr/bin/env bash
# Local single-node Slurm cluster for tests (tests/cluster, docs/cluster.md).
#
#   scripts/slurm_local.sh start|stop|status [--dir DIR] [--port N]
#
# start   write DIR/slurm.conf, start munged, slurmctld and slurmd, wait until the
#         node is idle. Idempotent: daemons already running from DIR are reused,
#         missing ones (e.g. a slurmd killed by hand) are restarted.
# stop    cancel the cluster's jobs, stop exactly the daemons started from DIR
#         (found through their pid files, checked against /proc), wait for them to
#         exit. Safe when nothing runs.
# status  print whether each daemon runs and what sinfo says; exit 0 when the whole
#         cluster runs, 3 otherwise.
#
# Everything (config, state, spool, logs, pid files, the munge socket) lives under
# DIR (default /tmp/ltbake-slurm). The munge key is the one the Debian package made
# (/etc/munge/munge.key). Needs root and the Debian packages slurm-wlm munge
# slurm-client; this script installs nothing.
#
# Environment: LTBAKE_SLURM_DIR (default DIR), LTBAKE_SLURM_PORT (slurmctld port,
# slurmd uses port+1; default 6817), LTBAKE_SLURM_TIMEOUT (seconds to wait for the
# node to become idle; default 60), LTBAKE_SLURM_MEM_MARGIN_MB (memory left out of
# RealMemory; default 1024), LTBAKE_SLURM_MIN_JOB_AGE (MinJobAge; default 5, which
# keeps sbatch --wait polling every 2 s instead of backing off to 8 and 32 s).
set -euo pipefail

usage() {
    echo "usage: $0 start|stop|status [--dir DIR] [--port N]" >&2
    exit 2
}

[ $# -ge 1 ] || usage
cmd=$1
shift
DIR=${LTBAKE_SLURM_DIR:-/tmp/ltbake-slurm}
PORT=${LTBAKE_SLURM_PORT:-6817}
TIMEOUT=${LTBAKE_SLURM_TIMEOUT:-60}
MEM_MARGIN_MB=${LTBAKE_SLURM_MEM_MARGIN_MB:-1024}
MIN_JOB_AGE=${LTBAKE_SLURM_MIN_JOB_AGE:-5}
while [ $# -gt 0 ]; do
    case $1 in
    --dir) [ $# -ge 2 ] || usage; DIR=$2; shift 2 ;;
    --dir=*) DIR=${1#--dir=}; shift ;;
    --port) [ $# -ge 2 ] || usage; PORT=$2; shift 2 ;;
    --port=*) PORT=${1#--port=}; shift ;;
    *) usage ;;
    esac
done
case $cmd in start | stop | status) ;; *) usage ;; esac
[[ $PORT =~ ^[0-9]+$ ]] || { echo "slurm_local: --port must be a number" >&2; exit 2; }

# Absolute path without requiring it to exist (realpath -m).
DIR=$(realpath -m -- "$DIR")
CONF=$DIR/etc/slurm.conf
MUNGE_DIR=$DIR/munge
MUNGE_SOCKET=$MUNGE_DIR/munge.socket.2
LOG_DIR=$DIR/log
RUN_DIR=$DIR/run
NODE=localhost
export SLURM_CONF=$CONF

log() { echo "slurm_local: $*" >&2; }
die() { log "error: $*"; exit 1; }

# --- processes ---------------------------------------------------------------

pidfile_of() {
    case $1 in
    munged) echo "$RUN_DIR/munged.pid" ;;
    slurmctld) echo "$RUN_DIR/slurmctld.pid" ;;
    slurmd) echo "$RUN_DIR/slurmd.pid" ;;
    esac
}

# Print the pid of daemon $1 when its pid file names a live process that is that
# daemon and was started from this DIR (its command line names DIR); else fail.
# A stale pid file whose pid was reused by another process is never trusted.
daemon_pid() {
    local name=$1 pf pid comm
    pf=$(pidfile_of "$name")
    [ -r "$pf" ] || return 1
    pid=$(tr -dc '0-9' 2>/dev/null <"$pf" || true)
    [ -n "$pid" ] || return 1
    [ -r "/proc/$pid/comm" ] || return 1
    comm=$(cat "/proc/$pid/comm" 2>/dev/null) || return 1
    [ "$comm" = "$name" ] || return 1
    tr '\0' ' ' 2>/dev/null <"/proc/$pid/cmdline" | grep -qF -- "$DIR/" || return 1
    echo "$pid"
}

running() { daemon_pid "$1" >/dev/null; }

# slurmstepd processes of this cluster outlive slurmd by design; they carry the
# SLURM_CONF of the slurmd that forked them, which names this DIR.
stepd_pids() {
    local p
    for p in $(pgrep -x slurmstepd 2>/dev/null || true); do
        if tr '\0' '\n' 2>/dev/null <"/proc/$p/environ" | grep -qxF -- "SLURM_CONF=$CONF"; then
            echo "$p"
        fi
    done
}

# Send TERM to pids, wait up to $2 seconds, then KILL what is left.
kill_wait() {
    local what=$1 secs=$2 p i alive
    shift 2
    [ $# -gt 0 ] || return 0
    kill -TERM "$@" 2>/dev/null || true
    for ((i = 0; i < secs * 10; i++)); do
        alive=0
        for p in "$@"; do
            if kill -0 "$p" 2>/dev/null && [ "$(cut -d' ' -f3 "/proc/$p/stat" 2>/dev/null)" != Z ]; then
                alive=1
            fi
        done
        [ $alive = 1 ] || return 0
        sleep 0.1
    done
    log "$what did not exit within ${secs}s after SIGTERM; sending SIGKILL"
    kill -KILL "$@" 2>/dev/null || true
    sleep 0.2
}

node_state() {
    timeout 10 sinfo -h -n "$NODE" -o '%T' 2>/dev/null | head -n1 || true
}

show_logs() {
    local f
    for f in "$LOG_DIR/munged.log" "$LOG_DIR/slurmctld.log" "$LOG_DIR/slurmd.log"; do
        [ -f "$f" ] || continue
        echo "----- tail of $f -----" >&2
        tail -n 25 "$f" >&2
    done
}

# --- start ---------------------------------------------------------------------

check_packages() {
    local missing=() b
    for b in munged slurmctld slurmd sinfo sbatch scontrol; do
        command -v "$b" >/dev/null 2>&1 || [ -x "/usr/sbin/$b" ] || missing+=("$b")
    done
    if [ ${#missing[@]} -gt 0 ]; then
        die "missing programs: ${missing[*]}. Install the Debian packages:
    apt-get install -y slurm-wlm munge slurm-client"
    fi
    [ -r /etc/munge/munge.key ] || die "/etc/munge/munge.key is missing (the munge package makes it; reinstall munge or run /usr/sbin/mungekey as root)"
    getent passwd munge >/dev/null || die "no 'munge' user (the munge package makes it)"
}

write_conf() {
    local cpus mem_kb mem_mb
    cpus=$(nproc)
    mem_kb=$(awk '/^MemTotal:/ {print $2}' /proc/meminfo)
    mem_mb=$((mem_kb / 1024 - MEM_MARGIN_MB))
    [ "$mem_mb" -ge 256 ] || mem_mb=256
    local tmp=$CONF.tmp.$$
    cat >"$tmp" <<EOF
# Written by scripts/slurm_local.sh; rewritten on every start.
ClusterName=ltbake
SlurmctldHost=localhost
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$MUNGE_SOCKET
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/builtin
SchedulerParameters=sched_interval=1
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
ReturnToService=2
MpiDefault=none
MailProg=/bin/true
KillWait=10
# sbatch --wait polls after 2 s, then every 8 s, then 32 s (2, 10, 42, 74 s ...)
# unless MinJobAge <= 5, where it keeps polling every 2 s. Finished jobs stay
# visible to squeue/scontrol for MinJobAge..MinJobAge+60 s.
MinJobAge=$MIN_JOB_AGE
SlurmctldTimeout=30
SlurmdTimeout=60
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$RUN_DIR/slurmctld.pid
SlurmdPidFile=$RUN_DIR/slurmd.pid
SlurmctldLogFile=$LOG_DIR/slurmctld.log
SlurmdLogFile=$LOG_DIR/slurmd.log
NodeName=$NODE CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=debug Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
    # Keep the running daemons' config untouched when nothing changed; when it
    # changed (other port, CPUs, memory), restart the slurm daemons still running.
    if [ -f "$CONF" ] && cmp -s "$tmp" "$CONF"; then
        rm -f "$tmp"
        return 0
    fi
    local n pid
    for n in slurmd slurmctld; do
        if pid=$(daemon_pid "$n"); then
            log "config changed: restarting $n"
            kill_wait "$n" 20 "$pid"
        fi
    done
    mv -f "$tmp" "$CONF"
}

port_busy() {
    ss -Hltn "sport = :$1" 2>/dev/null | grep -q .
}

start_munged() {
    running munged && return 0
    rm -f "$MUNGE_SOCKET" "$MUNGE_SOCKET.lock" "$(pidfile_of munged)"
    # munged refuses to run as root and checks that its directories are not
    # writable by others: give it its own directories owned by the munge user.
    chown munge: "$MUNGE_DIR" "$DIR/munge-log"
    chmod 0755 "$MUNGE_DIR"
    chmod 0700 "$DIR/munge-log"
    # Its pid file must be in a directory it can write: keep it in MUNGE_DIR and
    # point RUN_DIR/munged.pid at it.
    ln -sfn "$MUNGE_DIR/munged.pid" "$(pidfile_of munged)"
    runuser -u munge -- /usr/sbin/munged \
        --socket="$MUNGE_SOCKET" \
        --pid-file="$MUNGE_DIR/munged.pid" \
        --log-file="$DIR/munge-log/munged.log" \
        --seed-file="$MUNGE_DIR/munged.seed" \
        --key-file=/etc/munge/munge.key ||
        { cat "$DIR/munge-log/munged.log" >&2 2>/dev/null || true; die "munged failed to start"; }
    ln -sfn "$DIR/munge-log/munged.log" "$LOG_DIR/munged.log"
    local i
    for ((i = 0; i < 50; i++)); do
        [ -S "$MUNGE_SOCKET" ] && running munged && return 0
        sleep 0.1
    done
    show_logs
    die "munged did not come up (socket $MUNGE_SOCKET)"
}

start_slurmctld() {
    running slurmctld && return 0
    if port_busy "$PORT"; then
        die "port $PORT (slurmctld) is in use by another program; pick another with --port N or LTBAKE_SLURM_PORT"
    fi
    rm -f "$(pidfile_of slurmctld)"
    # -i: ignore state files that cannot be recovered (e.g. from another version).
    /usr/sbin/slurmctld -f "$CONF" -i || { show_logs; die "slurmctld failed to start"; }
}

start_slurmd() {
    running slurmd && return 0
    if port_busy "$((PORT + 1))"; then
        die "port $((PORT + 1)) (slurmd) is in use by another program; pick another with --port N or LTBAKE_SLURM_PORT"
    fi
    rm -f "$(pidfile_of slurmd)"
    /usr/sbin/slurmd -f "$CONF" -N "$NODE" || { show_logs; die "slurmd failed to start"; }
}

wait_idle() {
    local t0=$SECONDS state="" resumed=0
    while ((SECONDS - t0 < TIMEOUT)); do
        state=$(node_state)
        case $state in
        idle | mixed | allocated | completing) return 0 ;;
        drained | draining | drain* | down)
            # e.g. a slurmd killed by hand earlier: put the node back once.
            if [ $resumed = 0 ] && running slurmd; then
                timeout 10 scontrol update NodeName="$NODE" State=RESUME >/dev/null 2>&1 || true
                resumed=1
            fi
            ;;
        esac
        if ! running slurmctld; then
            show_logs
            die "slurmctld exited during startup"
        fi
        if ! running slurmd; then
            show_logs
            die "slurmd exited during startup"
        fi
        sleep 0.5
    done
    echo "slurm_local: last sinfo state: '${state:-<no answer>}'" >&2
    timeout 10 sinfo -N -l >&2 2>&1 || true
    show_logs
    die "node '$NODE' not idle after ${TIMEOUT}s (set LTBAKE_SLURM_TIMEOUT to wait longer); daemons left running for inspection, stop them with: $0 stop --dir $DIR"
}

do_start() {
    [ "$(id -u)" = 0 ] || die "must run as root (slurmd and munged need it)"
    check_packages
    mkdir -p "$DIR" "$DIR/etc" "$DIR/state" "$DIR/spool" "$LOG_DIR" "$RUN_DIR" \
        "$MUNGE_DIR" "$DIR/munge-log"
    chmod 0755 "$DIR" "$DIR/etc"
    chmod 0700 "$DIR/state" "$DIR/spool"
    local reused=1
    running munged && running slurmctld && running slurmd || reused=0
    if [ $reused = 0 ]; then
        write_conf
    elif [ ! -f "$CONF" ]; then
        die "daemons run from $DIR but $CONF is gone; run '$0 stop --dir $DIR' first"
    fi
    start_munged
    start_slurmctld
    start_slurmd
    wait_idle
    if [ $reused = 1 ]; then
        log "cluster in $DIR was already running; reused it"
    else
        log "cluster started in $DIR"
    fi
    cat <<EOF
Local Slurm cluster is up (node $NODE: $(node_state), partition debug, $(nproc) CPUs).
Use it from a shell with:
    export SLURM_CONF=$CONF
    sinfo; sbatch --wait --array=0-3 job.sh; squeue
Stop it with:
    $0 stop --dir $DIR
EOF
}

# --- stop ----------------------------------------------------------------------

do_stop() {
    [ "$(id -u)" = 0 ] || die "must run as root"
    local pid any=0 n
    # Cancel the jobs first so that no slurmstepd outlives slurmd.
    if running slurmctld && running munged; then
        timeout 10 scancel --full --partition=debug >/dev/null 2>&1 || true
    fi
    for n in slurmd slurmctld; do
        if pid=$(daemon_pid "$n"); then
            any=1
            kill_wait "$n" 20 "$pid"
        fi
        rm -f "$(pidfile_of "$n")"
    done
    # Left-over step daemons (e.g. slurmd was killed by hand with a job running).
    local steps
    steps=$(stepd_pids)
    if [ -n "$steps" ]; then
        any=1
        # shellcheck disable=SC2086
        kill_wait slurmstepd 10 $steps
    fi
    if pid=$(daemon_pid munged); then
        any=1
        kill_wait munged 10 "$pid"
    fi
    rm -f "$(pidfile_of munged)" "$MUNGE_DIR/munged.pid" "$MUNGE_SOCKET" "$MUNGE_SOCKET.lock"
    if [ $any = 1 ]; then
        log "stopped the cluster in $DIR"
    else
        log "nothing was running in $DIR"
    fi
}

# --- status --------------------------------------------------------------------

do_status() {
    local n pid all=1
    echo "dir: $DIR"
    for n in munged slurmctld slurmd; do
        if pid=$(daemon_pid "$n"); then
            echo "$n: running (pid $pid)"
        else
            echo "$n: not running"
            all=0
        fi
    done
    if [ $all = 1 ]; then
        echo "node $NODE: $(node_state)"
        echo "running; use: export SLURM_CONF=$CONF"
        return 0
    fi
    echo "not running (or only partly: '$0 start' restarts the missing daemons)"
    return 3
}

case $cmd in
start) do_start ;;
stop) do_stop ;;
status) do_status ;;
esac
