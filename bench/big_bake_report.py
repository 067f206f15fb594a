"""The per-stage table and the timeline plot of bench/big_bake.sh (run with /usr/bin/python3).

Reads the bake's run.json (per stage: wall and CPU seconds, block I/O, peak RSS, output
bytes), the sampler's timeline (cgroup memory and page cache, busy CPUs, disk bytes/s) and
/usr/bin/time's line for the whole run; writes OUT.md and OUT.png.
"""

import argparse
import datetime
import json
import os
import platform
import subprocess


def gib(b):
    return b / 2**30


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("run_json")
    ap.add_argument("timeline")
    ap.add_argument("time_txt")
    ap.add_argument("--r", type=int, required=True)
    ap.add_argument("--mem", required=True)
    ap.add_argument("--dd-write", type=float, required=True)
    ap.add_argument("--dd-read", type=float, required=True)
    ap.add_argument("--logical", type=int, required=True)
    ap.add_argument("--oom", default="0:0")
    ap.add_argument("--max-mem", type=int, default=0)
    ap.add_argument("--cgroup", default="none")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    run = json.load(open(a.run_json))
    wall, user, system, rss_kib = open(a.time_txt).read().split()[:4]
    wall, user, system = float(wall), float(user), float(system)
    floor = a.dd_write + a.dd_read

    rows = []
    t_first = None
    for s in run["stages"]:
        if s.get("status") != "done" or "wall_seconds" not in s:
            continue
        started = datetime.datetime.strptime(s["started"], "%Y-%m-%dT%H:%M:%S%z").timestamp()
        t_first = started if t_first is None else min(t_first, started)
        cpu = s.get("cpu_seconds", {})
        disk = s.get("disk_bytes", {})
        out = s.get("output", {})
        ins = sum(p.get("bytes", 0) for p in s.get("input_paths", []))
        rows.append({
            "node": s["node"], "started": started, "wall": s["wall_seconds"],
            "cpu": cpu.get("user", 0) + cpu.get("system", 0),
            "read": disk.get("read", 0), "written": disk.get("written", 0),
            "rss": s.get("peak_rss_bytes", 0), "out": out.get("bytes", 0), "in": ins,
            "hash": out.get("hash_seconds", 0),
        })
    total_wall = sum(r["wall"] for r in rows)
    moved = sum(r["read"] + r["written"] for r in rows)
    minimum = sum(r["in"] + r["out"] for r in rows)

    cpu_model = subprocess.run(["sh", "-c", "grep -m1 'model name' /proc/cpuinfo | cut -d: -f2"],
                               capture_output=True, text=True).stdout.strip()
    mem_total = int(open("/proc/meminfo").readline().split()[1]) / 2**20
    oom_before, oom_after = (int(x or 0) for x in a.oom.split(":"))
    lines = [
        f"# The R = {a.r} bake end to end in a {a.mem} memory cgroup (issue 23, part 3)",
        "",
        f"Machine: {os.cpu_count()} × {cpu_model}, {mem_total:.1f} GiB, {platform.release()}, "
        f"{datetime.date.today()}; load average before the run: "
        f"{open('/proc/loadavg').read().split()[0]} (1 min, at the end).",
        f"Bake: `ltbake run` of samples/medium.toml at R = {a.r} (256×256 pixels, spp 1, "
        f"{a.logical / 1e9:.1f} GB logical), fused sample + row-transform (Haar), transpose, "
        "column-transform (adaptive LeGall 5/3, keep 0.02), quantize, one relight. "
        f"Cgroup: `{a.cgroup}` (page cache counted), stages given `--mem-limit` = ¾ of it.",
        f"Reproduce: `sudo bash bench/big_bake.sh build {a.r} {a.mem}`.",
        "",
        f"- **Whole run: {wall:.1f} s wall, {user + system:.1f} s CPU** ({user:.1f} user + {system:.1f} system); "
        f"stages {total_wall:.1f} s of it.",
        f"- I/O floor (dd, same cgroup, {a.logical / 1e9:.1f} GB): write+fdatasync {a.dd_write:.1f} s, "
        f"read {a.dd_read:.1f} s, **{floor:.1f} s**; the bake is **{wall / floor:.1f}× the floor**.",
        f"- OOM kills in the cgroup during the run: {oom_after - oom_before}; its peak usage "
        f"{gib(a.max_mem):.2f} GiB (page cache included).",
        f"- Bytes moved to and from the disk by the stages: {gib(moved):.2f} GiB; reading each input "
        f"once and writing each output once is {gib(minimum):.2f} GiB: **{moved / max(minimum, 1):.2f}×** "
        "(block I/O from rusage; page-cache hits are not disk traffic).",
        "",
        "| stage | wall s | CPU s | CPU/wall | disk read GiB | disk written GiB | inputs GiB | output GiB | peak RSS MiB | hash s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['node']} | {r['wall']:.1f} | {r['cpu']:.1f} | {r['cpu'] / max(r['wall'], 1e-9):.2f} | "
            f"{gib(r['read']):.2f} | {gib(r['written']):.2f} | {gib(r['in']):.2f} | {gib(r['out']):.2f} | "
            f"{r['rss'] / 2**20:.0f} | {r['hash']:.2f} |")
    open(a.out + ".md", "w").write("\n".join(lines) + "\n")
    print("\n".join(lines))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, mem, cache, cpus, rd, wr = [], [], [], [], [], []
    with open(a.timeline) as f:
        next(f)
        for line in f:
            p = line.rstrip("\n").split("\t")
            if len(p) < 6 or "" in p:
                continue
            t.append(float(p[0]))
            mem.append(int(p[1]) / 2**30)
            cache.append(int(p[2]) / 2**30)
            cpus.append(float(p[3]))
            rd.append(int(p[4]) / 2**20)
            wr.append(int(p[5]) / 2**20)
    # The sampler starts before dd; the bake's first stage starts `offset` seconds into it.
    sampler_start = os.path.getmtime(a.timeline) - (t[-1] if t else 0)
    offset = (t_first - sampler_start) if t_first else 0
    fig, ax = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    ax[0].plot(t, cpus, lw=1)
    ax[0].set_ylabel("busy CPUs")
    ax[0].set_ylim(0, os.cpu_count() + 0.2)
    ax[1].plot(t, rd, lw=1, label="disk read")
    ax[1].plot(t, wr, lw=1, label="disk write")
    ax[1].set_ylabel("MiB/s")
    ax[1].legend(loc="upper right")
    ax[2].plot(t, mem, lw=1, label="cgroup memory")
    ax[2].plot(t, cache, lw=1, label="of it page cache")
    ax[2].set_ylabel("GiB")
    ax[2].set_xlabel("seconds")
    ax[2].legend(loc="upper right")
    for r in rows:
        x0 = r["started"] - sampler_start
        for axis in ax:
            axis.axvline(x0, color="grey", lw=0.5)
        ax[0].text(x0, os.cpu_count() + 0.05, r["node"], fontsize=7, rotation=30)
    fig.suptitle(f"ltbake run, R = {a.r}, in {a.mem}: {wall:.0f} s wall, {user + system:.0f} s CPU")
    fig.tight_layout()
    fig.savefig(a.out + ".png", dpi=90)


if __name__ == "__main__":
    main()
