#!/usr/bin/env bash
# Smoke test of the local single-node Slurm cluster (scripts/slurm_local.sh),
# the Slurm behaviour sharded bakes rely on (tests/cluster/slurm_bake_test.sh runs the bakes; not in make test).
#
# Starts a cluster in its own directory and port (LTBAKE_SLURM_DIR, default
# /tmp/ltbake-slurm-test; LTBAKE_SLURM_PORT, default 6837) and always stops it on exit:
#   1. sbatch --wait --array=0-3: every task writes one file from
#      SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT (both must be set);
#   2. a second array whose task 2 sleeps and is cancelled with scancel JOBID_2:
#      sbatch --wait must fail, task 2 must have received SIGTERM (its trap writes a
#      marker), the other outputs must exist;
#   3. rerunning the whole array redoes only the missing task (tasks are idempotent).
# Prints the wall time of each step. Exit 0 pass, 1 fail, 77 cannot run here (not
# root, or slurm-wlm/munge/slurm-client missing and not installable).
set -euo pipefail

HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
SL=$ROOT/scripts/slurm_local.sh
export LTBAKE_SLURM_DIR=${LTBAKE_SLURM_DIR:-/tmp/ltbake-slurm-test}
export LTBAKE_SLURM_PORT=${LTBAKE_SLURM_PORT:-6837}
WAIT_LIMIT=${SMOKE_WAIT_LIMIT:-120} # seconds any single sbatch --wait may take

skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*" >&2; exit 1; }

# --- preflight -------------------------------------------------------------------
[ "$(id -u)" = 0 ] || skip "needs root (munged, slurmd)"
have_pkgs() { command -v sbatch >/dev/null && [ -x /usr/sbin/slurmctld ] && [ -x /usr/sbin/slurmd ] && [ -x /usr/sbin/munged ]; }
if ! have_pkgs; then
    echo "installing slurm-wlm munge slurm-client (Debian) ..."
    if ! DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge slurm-client >/tmp/slurm-smoke-apt.log 2>&1; then
        DEBIAN_FRONTEND=noninteractive apt-get update -q >>/tmp/slurm-smoke-apt.log 2>&1 || true
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge slurm-client >>/tmp/slurm-smoke-apt.log 2>&1 ||
            skip "cannot install slurm-wlm munge slurm-client (see /tmp/slurm-smoke-apt.log)"
    fi
    have_pkgs || skip "slurm-wlm munge slurm-client still missing after apt-get install"
fi

WORK=$(mktemp -d /tmp/ltbake-slurm-smoke.XXXXXX)
RESULT=fail
cleanup() {
    local rc=$?
    trap - EXIT INT TERM
    # Stop the cluster whatever happened (no-op when already stopped).
    "$SL" stop >/dev/null 2>&1 || echo "warning: slurm_local.sh stop failed" >&2
    if [ "$RESULT" = pass ]; then
        rm -rf "$WORK"
    elif [ "$rc" != 77 ]; then
        echo "work files kept in $WORK" >&2
        for f in "$WORK"/slurm-*.out; do
            [ -s "$f" ] && { echo "--- $f"; cat "$f"; } >&2
        done
        rc=1
    fi
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 1' INT TERM

now() { date +%s.%N; }
T0=$(now)
TSTEP=$T0
STEP=""
step() { # step NAME: starts timing NAME, closes the previous step
    end_step
    STEP=$1
    TSTEP=$(now)
    echo "== $STEP"
}
end_step() {
    [ -n "$STEP" ] || return 0
    printf '   %-46s %6.2f s\n' "$STEP" "$(awk "BEGIN{print $(now) - $TSTEP}")"
    STEP=""
}

export SLURM_CONF=$LTBAKE_SLURM_DIR/etc/slurm.conf

# The job: one output per task, idempotent (an existing output is skipped), records
# that it did work in ran/, and when it is the task named by SLEEP_TASK it sleeps
# until cancelled, writing a marker when SIGTERM arrives.
cat >"$WORK/job.sh" <<'EOF'
#!/bin/bash
set -eu
: "${SLURM_ARRAY_TASK_ID:?SLURM_ARRAY_TASK_ID not set}"
: "${SLURM_ARRAY_TASK_COUNT:?SLURM_ARRAY_TASK_COUNT not set}"
: "${SLURM_ARRAY_JOB_ID:?SLURM_ARRAY_JOB_ID not set}"
i=$SLURM_ARRAY_TASK_ID
out=$OUTDIR/out_$i.txt
if [ -e "$out" ]; then
    echo "task $i: $out exists, skipped"
    exit 0
fi
mkdir -p "$OUTDIR/ran"
echo "$SLURM_ARRAY_JOB_ID" >"$OUTDIR/ran/${SLURM_ARRAY_JOB_ID}_$i"
if [ "$i" = "${SLEEP_TASK:-none}" ]; then
    trap 'echo "SIGTERM $(date +%s.%N)" >"$OUTDIR/term_$i"; exit 143' TERM
    touch "$OUTDIR/started_$i"
    sleep 300 &
    wait $!
fi
echo "task $i of $SLURM_ARRAY_TASK_COUNT" >"$out.tmp.$$"
mv "$out.tmp.$$" "$out"
EOF
chmod +x "$WORK/job.sh"

wait_for() { # wait_for SECONDS DESCRIPTION TEST-COMMAND...
    local secs=$1 what=$2 t
    shift 2
    t=$SECONDS
    until "$@"; do
        ((SECONDS - t < secs)) || fail "timed out after ${secs}s waiting for $what"
        sleep 0.2
    done
}

check_outputs() { # check_outputs DIR N: DIR/out_i.txt for i < N say "task i of N"
    local d=$1 n=$2 i
    for ((i = 0; i < n; i++)); do
        [ -f "$d/out_$i.txt" ] || fail "missing output $d/out_$i.txt"
        [ "$(cat "$d/out_$i.txt")" = "task $i of $n" ] ||
            fail "out_$i.txt says '$(cat "$d/out_$i.txt")', expected 'task $i of $n'"
    done
}

# --- 1. start ----------------------------------------------------------------------
step "start cluster"
"$SL" start >"$WORK/start.log" 2>&1 || { cat "$WORK/start.log" >&2; fail "slurm_local.sh start failed"; }
"$SL" status >/dev/null || fail "status says not running right after start"

step "start again (idempotent, reuses the cluster)"
pids_before=$(cat "$LTBAKE_SLURM_DIR"/run/*.pid | sort | tr '\n' ' ')
"$SL" start >"$WORK/start2.log" 2>&1 || { cat "$WORK/start2.log" >&2; fail "second start failed"; }
grep -q "reused" "$WORK/start2.log" || fail "second start did not reuse the running cluster"
pids_after=$(cat "$LTBAKE_SLURM_DIR"/run/*.pid | sort | tr '\n' ' ')
[ "$pids_before" = "$pids_after" ] || fail "second start replaced daemons ($pids_before -> $pids_after)"

# --- 2. a plain array ----------------------------------------------------------------
step "sbatch --wait --array=0-3 (4 tasks)"
mkdir -p "$WORK/a"
timeout "$WAIT_LIMIT" sbatch --wait --quiet --array=0-3 --job-name=smoke-a \
    --output="$WORK/slurm-a-%A_%a.out" --chdir="$WORK" \
    --export=ALL,OUTDIR="$WORK/a" "$WORK/job.sh" ||
    fail "array 0-3 failed (sbatch --wait rc=$?)"
check_outputs "$WORK/a" 4

# --- 3. cancel one task mid-run ------------------------------------------------------
step "array with task 2 cancelled mid-run"
mkdir -p "$WORK/b"
set +e
timeout "$WAIT_LIMIT" sbatch --wait --quiet --array=0-3 --job-name="smoke-b-$$" \
    --output="$WORK/slurm-b-%A_%a.out" --chdir="$WORK" \
    --export=ALL,OUTDIR="$WORK/b",SLEEP_TASK=2 "$WORK/job.sh" &
sb_pid=$!
set -e
wait_for 60 "task 2 to start" test -e "$WORK/b/started_2"
wait_for 60 "tasks 0, 1, 3 to finish" test -e "$WORK/b/out_0.txt" -a -e "$WORK/b/out_1.txt" -a -e "$WORK/b/out_3.txt"
jobid=$(squeue -h --name="smoke-b-$$" -o '%F' | head -n1)
[ -n "$jobid" ] || fail "cannot find the array job id of smoke-b-$$ in squeue"
echo "   scancel ${jobid}_2"
scancel "${jobid}_2"
# Read the state now: finished records are purged MinJobAge (5 s) to 65 s after the end.
task2_state() { scontrol show job "${jobid}_2" 2>/dev/null | grep -o 'JobState=[A-Z_]*' | head -n1 || true; }
task2_cancelled() { [ "$(task2_state)" = JobState=CANCELLED ]; }
wait_for 30 "task 2 to be in JobState=CANCELLED" task2_cancelled
set +e
wait "$sb_pid"
sb_rc=$?
set -e
echo "   sbatch --wait returned $sb_rc"
[ "$sb_rc" != 124 ] || fail "sbatch --wait still waiting after ${WAIT_LIMIT}s"
[ "$sb_rc" != 0 ] || fail "sbatch --wait returned 0 although task 2 was cancelled"
[ -f "$WORK/b/term_2" ] || fail "task 2 did not receive SIGTERM (no marker written by its trap)"
[ ! -e "$WORK/b/out_2.txt" ] || fail "cancelled task 2 wrote its output"

# --- 4. rerun: only the missing task works -------------------------------------------
step "rerun array 0-3: only task 2 redone"
find "$WORK/b/ran" -type f -printf '%f\n' >"$WORK/ran_before"
timeout "$WAIT_LIMIT" sbatch --wait --quiet --array=0-3 --job-name=smoke-c \
    --output="$WORK/slurm-c-%A_%a.out" --chdir="$WORK" \
    --export=ALL,OUTDIR="$WORK/b" "$WORK/job.sh" ||
    fail "rerun failed (sbatch --wait rc=$?)"
check_outputs "$WORK/b" 4
new=$(find "$WORK/b/ran" -type f -printf '%f\n' | grep -vxF -f "$WORK/ran_before" | sed 's/.*_//' | sort | tr '\n' ' ' || true)
[ "$new" = "2 " ] || fail "rerun did work for tasks '$new', expected only '2 '"

# --- 5. stop -------------------------------------------------------------------------
step "stop cluster"
"$SL" stop >/dev/null 2>&1 || fail "slurm_local.sh stop failed"
if "$SL" status >/dev/null 2>&1; then fail "status says running after stop"; fi
for f in "$LTBAKE_SLURM_DIR"/run/*.pid; do
    if [ -e "$f" ]; then fail "pid file $f left after stop"; fi
done
end_step

printf '   %-46s %6.2f s\n' "total" "$(awk "BEGIN{print $(now) - $T0}")"
RESULT=pass
echo "slurm smoke test: 1 passed, 0 failed"
