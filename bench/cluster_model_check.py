"""docs/cluster.md's scaling model, T = max(C / cores, V / B) per stage, against shard runs through
the real single-node Slurm (scripts/slurm_local.sh).

1. B: dd of 2 GiB to OUT (conv=fdatasync) and back (iflag=direct), the slower of the two.
2. The medium scene (samples/medium.toml, spp 4) at R = CUBE_RES baked by `ltbake run` unsharded
   (local engine, --jobs 2): each stage's core-seconds C (user + system) and bytes V (its input
   files and its output, run.json's input_paths and output).
3. The same bake with `--engine slurm --shards S --jobs 1` for S = 2 and 4: S shards of one CPU
   on the machine's 2, so ceil(S/2) waves of C/S core-seconds each; the model's stage time is
   max(waves · C/S, V/B), and `sbatch --wait` reports a job only when it polls (every 2 s with
   the local Slurm's MinJobAge = 5), so what `run` can measure is the model's time rounded up to
   the next poll. The table sets each stage's measured wall time beside both.

usage: SLURM_CONF=/tmp/ltbake-slurm/etc/slurm.conf /usr/bin/python3 bench/cluster_model_check.py PATH_TO_LTBAKE OUT [CUBE_RES=32]
(start the cluster first: scripts/slurm_local.sh start). Writes OUT/cluster_model_check.md. ~5 min at R = 32.
"""
import datetime
import math
import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import benchlib  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
POLL = 2.0  # seconds between sbatch --wait's polls of the local cluster (MinJobAge = 5)


def dd_bandwidth(out):
    """The slower of dd's write (fdatasync) and direct read of 2 GiB, bytes/s."""
    path = os.path.join(out, "dd.bin")
    rates = []
    for args in (["if=/dev/zero", f"of={path}", "bs=8M", "count=256", "conv=fdatasync"],
                 [f"if={path}", "of=/dev/null", "bs=8M", "iflag=direct"]):
        p = subprocess.run(["dd", *args], capture_output=True, text=True)
        line = [l for l in p.stderr.splitlines() if "copied" in l][-1]
        seconds = float(line.split(",")[-2].split()[0])
        rates.append(256 * 8 * 2 ** 20 / seconds)
    os.remove(path)
    return min(rates), rates


def shard_seconds(log_text):
    """Per job array (in submission order), each task's seconds from allocation to completion,
    from the slurmctld log lines of one bake."""
    start, jobs = {}, {}
    for line in log_text.splitlines():
        m = re.match(r"\[(\S+)\] sched: Allocate JobId=(\d+)_(\d+)", line)
        if m:
            start[(m.group(2), m.group(3))] = datetime.datetime.fromisoformat(m.group(1))
            jobs.setdefault(m.group(2), [])
        m = re.match(r"\[(\S+)\] _job_complete: JobId=(\d+)_(\d+)\(\d+\) WEXITSTATUS", line)
        if m and (m.group(2), m.group(3)) in start:
            t = datetime.datetime.fromisoformat(m.group(1)) - start[(m.group(2), m.group(3))]
            jobs[m.group(2)].append(t.total_seconds())
    return [jobs[j] for j in sorted(jobs, key=int)]


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    ltbake, out = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
    r = int(sys.argv[3]) if len(sys.argv) > 3 else 32
    if not os.environ.get("SLURM_CONF"):
        sys.exit("set SLURM_CONF (scripts/slurm_local.sh start prints it)")
    os.makedirs(out, exist_ok=True)
    recipe = os.path.join(out, "bake.toml")
    with open(recipe, "w") as f:
        f.write(f'name = "model-check"\nscene = "{REPO}/samples/medium.toml"\ntargets = ["quantize"]\n'
                f'keep = ["rows", "cols", "cols4d"]\n[sample]\ncube_res = {r}\n')
    b, (bw, br) = dd_bandwidth(out)
    local = benchlib.run_bake(ltbake, recipe, os.path.join(out, "s1"), "-q", "--jobs", "2")
    cost = {}
    for s in local:
        cpu = s.get("cpu_seconds", {})
        v = sum(p.get("bytes") or 0 for p in s.get("input_paths", [])) + s["output"].get("bytes", 0)
        cost[s["node"]] = (cpu.get("user", 0) + cpu.get("system", 0), v, s["wall_seconds"])
    lines = ["# docs/cluster.md's model against shard runs on one node", "",
             f"`/usr/bin/python3 bench/cluster_model_check.py build/ltbake OUT {r}`; the medium scene at R = {r} "
             f"({65536 * 6 * r * r * 4 / 1e9:.2f} GB of f32 matrix). B = {b / 1e6:.0f} MB/s (dd write "
             f"{bw / 1e6:.0f}, direct read {br / 1e6:.0f} MB/s). C, V: the unsharded local bake (--jobs 2). "
             f"Machine: {benchlib.machine()}.", "",
             "Model: S shards of one CPU on 2 cores, ceil(S/2) waves of C/S core-seconds, against the I/O "
             "term V/B; a stage ends at the first `sbatch --wait` poll (every 2 s) after its last shard. Measured: "
             "each shard's seconds from the slurmctld log (allocation to completion), the stage's wall time "
             "from run.json.", "",
             "| stage | S | C (core-s) | V (GB) | model: shard C/S; stage max(waves·C/S, V/B) | measured: shards | "
             "measured: stage | stage / model |", "|---|---|---|---|---|---|---|---|"]
    for node, (c, v, wall) in cost.items():
        model = max(c / 2, v / b)
        lines.append(f"| {node} | 1 (local) | {c:.1f} | {v / 1e9:.2f} | –; {model:.1f} s | – | {wall:.1f} s | "
                     f"{wall / model:.2f} |")
    log = os.path.join(os.environ.get("LTBAKE_SLURM_DIR", "/tmp/ltbake-slurm"), "log", "slurmctld.log")
    for shards in (2, 4):
        at = os.path.getsize(log)
        stages = benchlib.run_bake(ltbake, recipe, os.path.join(out, f"s{shards}"), "-q", "--engine", "slurm",
                                   "--shards", str(shards), "--jobs", "1")
        with open(log) as f:
            f.seek(at)
            arrays = shard_seconds(f.read())
        for k, s in enumerate(stages):
            c, v, _ = cost[s["node"]]
            model = max(math.ceil(shards / 2) * c / shards, v / b)
            polled = POLL * math.ceil(model / POLL)
            tasks = arrays[k] if k < len(arrays) else []
            lines.append(f"| {s['node']} | {shards} | {c:.1f} | {v / 1e9:.2f} | {c / shards:.1f} s; {model:.1f} s "
                         f"({polled:.0f} s at the poll) | {', '.join('%.1f' % t for t in tasks)} s | "
                         f"{s['wall_seconds']:.1f} s | {s['wall_seconds'] / polled:.2f} |")
    benchlib.write_report(os.path.join(out, "cluster_model_check.md"), lines)


if __name__ == "__main__":
    main()
