#!/usr/bin/env bash
# Cluster test: a sharded bake through a real single-node Slurm cluster.
#
#   1. the reference: the same recipe run locally, unsharded;
#   2. `ltbake run --engine slurm --shards 4 --retries 0`; while the sample step's job
#      array runs, its task 2 is cancelled (scancel JOBID_2) -> the run fails naming shard 2;
#   3. the rerun submits only shard 2 of the sample step (run.json: shards 0, 1, 3
#      "skipped", 2 "done"), then runs every later stage as 4-task arrays;
#   4. every output's content_hash equals the unsharded run's; verify passes on the manifests;
#   5. `--retries 1` resubmits a cancelled task by itself (a second work directory given
#      step 3's rows with --from transpose, the transpose step's task 1 cancelled): the run
#      succeeds and records 2 attempts.
# The cluster runs in its own directory and port and is stopped on any exit.
# Usage: slurm_bake_test.sh LTBAKE. Exit 0 pass, 1 fail, 77 cannot run (not root).
set -euo pipefail

LTBAKE=$(readlink -f "${1:?usage: slurm_bake_test.sh LTBAKE}")
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
SL=$ROOT/scripts/slurm_local.sh
PY=/usr/bin/python3
export LTBAKE_SLURM_DIR=${LTBAKE_SLURM_DIR:-/tmp/ltbake-slurm-bake}
export LTBAKE_SLURM_PORT=${LTBAKE_SLURM_PORT:-6847}

skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*" >&2; exit 1; }
T0=$(date +%s.%N)
say() { printf '[%6.1f s] %s\n' "$(echo "$(date +%s.%N) - $T0" | bc)" "$*"; }

[ "$(id -u)" = 0 ] || skip "needs root (munged, slurmd)"
have_pkgs() { command -v sbatch >/dev/null && [ -x /usr/sbin/slurmctld ] && [ -x /usr/sbin/slurmd ] && [ -x /usr/sbin/munged ]; }
if ! have_pkgs; then
    say "installing slurm-wlm munge slurm-client (Debian)"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge slurm-client >/tmp/slurm-bake-apt.log 2>&1 ||
        { DEBIAN_FRONTEND=noninteractive apt-get update -q >>/tmp/slurm-bake-apt.log 2>&1;
          DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge slurm-client >>/tmp/slurm-bake-apt.log 2>&1; } ||
        fail "cannot install slurm-wlm munge slurm-client (see /tmp/slurm-bake-apt.log)"
    have_pkgs || fail "slurm-wlm munge slurm-client still missing after apt-get install"
fi

WORK=$(mktemp -d /tmp/ltbake-slurm-bake.XXXXXX)
RESULT=fail
BG=""
cleanup() {
    local rc=$?
    trap - EXIT INT TERM
    [ -n "$BG" ] && kill "$BG" 2>/dev/null || true
    "$SL" stop >/dev/null 2>&1 || echo "warning: slurm_local.sh stop failed" >&2
    if [ "$RESULT" = pass ]; then
        rm -rf "$WORK"
    else
        echo "work files kept in $WORK" >&2
        for f in "$WORK"/*.out "$WORK"/slurm*/logs/*.log; do
            [ -s "$f" ] && { echo "--- $f"; tail -n 20 "$f"; } >&2
        done
        rc=1
    fi
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 1' INT TERM

hash_of() { "$LTBAKE" inspect --json "$1" | $PY -c 'import json,sys; print(json.load(sys.stdin)["content_hash"])'; }
# wait_for SECONDS WHAT CMD...: polls CMD every 0.2 s
wait_for() {
    local limit=$1 what=$2; shift 2
    local end=$(( $(date +%s) + limit ))
    until "$@"; do
        [ "$(date +%s)" -lt "$end" ] || fail "timed out after ${limit} s waiting for $what"
        sleep 0.2
    done
}
# task_running PREFIX I: task I of the job array whose name starts with PREFIX is RUNNING;
# task_id PREFIX I: its id (JOBID_I), pending or running (-r: one line per array task).
task_running() { squeue -h -r -o '%i %j %T' | awk -v p="$1" -v t="_$2" '$2 ~ "^"p && $3 == "RUNNING" && substr($1, length($1)-length(t)+1) == t {print $1}' | grep -q .; }
task_queued() { [ -n "$(task_id "$1" "$2")" ]; }
task_id() { squeue -h -r -o '%i %j %T' | awk -v p="$1" -v t="_$2" '$2 ~ "^"p && substr($1, length($1)-length(t)+1) == t {print $1}' | head -n1; }

# A recipe whose sample shards take a few seconds each (R = 32, 128 spp on samples/tiny.toml).
cat >"$WORK/bake.toml" <<TOML
name = "slurm-test"
scene = "$ROOT/samples/tiny.toml"
targets = ["quantize"]
keep = ["rows", "cols", "cols4d"]
[sample]
cube_res = 32
spp = 128
[column-transform]
keep = 0.05
TOML

say "1. reference: local, unsharded"
"$LTBAKE" run "$WORK/bake.toml" --workdir "$WORK/local" -q >"$WORK/local.out" 2>&1 || fail "unsharded local run failed"
declare -A REF
for f in rows cols cols4d final; do REF[$f]=$(hash_of "$WORK/local/$f.ltm"); done
say "   final.ltm content_hash ${REF[final]}"

say "starting the single-node cluster"
"$SL" start >"$WORK/start.out" 2>&1 || { cat "$WORK/start.out" >&2; fail "slurm_local.sh start failed"; }
export SLURM_CONF=$LTBAKE_SLURM_DIR/etc/slurm.conf

say "2. slurm, 4 shards, --retries 0; cancel task 2 of the sample array mid-run"
W=$WORK/slurm
# First the plan: --dry-run shows each step's job array and script (checked against what the
# runs below submit and write) and makes nothing.
"$LTBAKE" run "$WORK/bake.toml" --workdir "$W" --engine slurm --shards 4 --cpus-per-task 1 --retries 0 \
    --dry-run --json >"$WORK/plan.json" || fail "the dry run failed"
[ ! -e "$W" ] || fail "the dry run made $W"
"$LTBAKE" run "$WORK/bake.toml" --workdir "$W" --engine slurm --shards 4 --cpus-per-task 1 --retries 0 \
    >"$WORK/run1.out" 2>&1 &
BG=$!
wait_for 120 "task 2 of the sample array to run" task_running ltbake-sample 2
tid=$(task_id ltbake-sample 2)
say "   scancel $tid"
scancel "$tid"
rc=0
wait "$BG" || rc=$?
BG=""
[ "$rc" = 1 ] || { cat "$WORK/run1.out" >&2; fail "the run with a cancelled shard exited $rc, expected 1"; }
grep -q "shard 2 " "$WORK/run1.out" || { cat "$WORK/run1.out" >&2; fail "the failure does not name shard 2"; }
[ ! -e "$W/rows.ltm" ] || fail "rows.ltm (the manifest) was written although shard 2 failed"
$PY - "$W/run.json" <<'PY' || fail "run.json after the cancelled run is not as expected"
import json, sys
st = {s["node"]: s for s in json.load(open(sys.argv[1]))["stages"]}
s = st["sample+row-transform"]
assert s["status"] == "failed", s["status"]
shards = {x["index"]: x for x in s["shards"]}
assert shards[2]["status"] == "failed", shards[2]
assert all(shards[i]["status"] == "done" for i in (0, 1, 3)), shards
print("   run.json: sample shards 0,1,3 done, 2 failed")
PY

say "3. rerun: only shard 2 of the sample step is submitted"
"$LTBAKE" run "$WORK/bake.toml" --workdir "$W" --engine slurm --shards 4 --cpus-per-task 1 --retries 0 \
    >"$WORK/run2.out" 2>&1 || { cat "$WORK/run2.out" >&2; fail "the rerun failed"; }
grep -q -- "--array=2 " "$WORK/run2.out" || { cat "$WORK/run2.out" >&2; fail "the rerun did not submit --array=2 alone"; }
$PY - "$W/run.json" <<'PY' || fail "run.json after the rerun is not as expected"
import json, sys
st = {s["node"]: s for s in json.load(open(sys.argv[1]))["stages"]}
s = st["sample+row-transform"]
shards = {x["index"]: x for x in s["shards"]}
assert [shards[i]["status"] for i in range(4)] == ["skipped", "done", "skipped", "skipped"][:0] or \
    [shards[i]["status"] for i in range(4)] == ["skipped", "skipped", "done", "skipped"], shards
assert shards[2]["attempts"] == 1, shards[2]
assert len(s["submissions"]) == 1 and "--array=2 " in s["submissions"][0], s["submissions"]
for node in ("transpose", "column-transform", "quantize"):
    e = st[node]
    assert e["status"] == "done" and e["nshards"] == 4 and e["engine"] == "slurm", e
    assert all(x["status"] == "done" for x in e["shards"]), e["shards"]
print("   run.json: sample shard 2 ran alone; later stages ran 4 shards each")
PY
$PY - "$W/run.json" "$WORK/plan.json" "$W/logs" <<'PY' || fail "the dry run's job arrays are not what the run submitted"
import json, os, sys
st = {s["node"]: s for s in json.load(open(sys.argv[1]))["stages"]}
plan = {p["node"]: p for p in json.load(open(sys.argv[2]))["plan"]}
same = lambda line: [w for w in line.split()[1:] if not w.startswith("--job-name=")]  # sbatch's path, the run's tag
for node in ("transpose", "column-transform", "quantize"):
    sl = plan[node]["slurm"]
    assert "--array=0-3 " in sl["submit"] and same(sl["submit"]) == same(st[node]["submissions"][0]), (sl, st[node])
    assert open(sl["script_path"]).read() == sl["script"], sl["script_path"]
print("   --dry-run: the job arrays and scripts it showed are the ones submitted")
PY
[ -s "$W/logs/sample+row-transform.shard-2.log" ] || fail "no log of shard 2"

say "4. outputs equal the unsharded run"
for f in rows cols cols4d final; do
    h=$(hash_of "$W/$f.ltm")
    [ "$h" = "${REF[$f]}" ] || fail "$f.ltm content_hash $h, unsharded ${REF[$f]}"
    head -c 17 "$W/$f.ltm" | grep -q "LTBAKE-MANIFEST" || fail "$f.ltm is not a stage manifest"
    "$LTBAKE" verify "$W/$f.ltm" >/dev/null || fail "verify $f.ltm failed"
done
say "   rows, cols, cols4d, final: content_hash equal (final ${REF[final]})"

say "5. --retries 1: a cancelled transpose task is resubmitted by the run itself"
W2=$WORK/slurm-retry
# The sample step's output from step 3 (the manifest and its shards), given with --from:
# sampling again would only repeat step 3's work.
mkdir -p "$W2"
cp -r "$W/rows.ltm" "$W/rows.shards" "$W2/"
# transpose shards are quick: hold them with a job that takes both CPUs, cancel task 1 while pending
hold=$(sbatch --parsable --cpus-per-task=2 --job-name=hold --output=/dev/null --wrap "sleep 600")
"$LTBAKE" run "$WORK/bake.toml" --workdir "$W2" --engine slurm --shards 4 --cpus-per-task 1 --retries 1 \
    --from transpose >"$WORK/run3.out" 2>&1 &
BG=$!
wait_for 60 "the transpose array to be queued" task_queued ltbake-transpose 1
tid=$(task_id ltbake-transpose 1)
say "   scancel $tid (pending), then release the CPUs"
scancel "$tid"
scancel "$hold"
rc=0
wait "$BG" || rc=$?
BG=""
[ "$rc" = 0 ] || { cat "$WORK/run3.out" >&2; fail "the run with --retries 1 exited $rc"; }
grep -q "resubmitting shards 1 " "$WORK/run3.out" || { cat "$WORK/run3.out" >&2; fail "no resubmission of shard 1"; }
$PY - "$W2/run.json" <<'PY' || fail "run.json of the retried run is not as expected"
import json, sys
st = {s["node"]: s for s in json.load(open(sys.argv[1]))["stages"]}
t = {x["index"]: x for x in st["transpose"]["shards"]}
assert t[1]["status"] == "done" and t[1]["attempts"] == 2, t[1]
assert len(st["transpose"]["submissions"]) == 2, st["transpose"]["submissions"]
print("   run.json: transpose shard 1 done after 2 attempts")
PY
h=$(hash_of "$W2/final.ltm")
[ "$h" = "${REF[final]}" ] || fail "final.ltm after a retry: content_hash $h, unsharded ${REF[final]}"

say "stopping the cluster"
"$SL" stop >/dev/null 2>&1 || fail "slurm_local.sh stop failed"
"$SL" status >/dev/null 2>&1 && fail "daemons still running after stop"
RESULT=pass
say "PASS"
