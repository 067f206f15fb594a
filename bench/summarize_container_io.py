#!/usr/bin/env python3
"""Summarizes bench/results/container_io.jsonl (written by run_container_io.sh) into a
Markdown report: machine, medians, container/dd ratios, reader peak RSS, verdicts.

usage: summarize_container_io.py JSONL OUT_MD SIZE_GIB REPS DROP_CACHES OUT_DIR COMMAND
"""
import datetime
import json
import os
import statistics
import subprocess
import sys


def sh(cmd):
    try:
        return subprocess.run(cmd, shell=True, capture_output=True, text=True, timeout=30).stdout.strip()
    except Exception:  # noqa: BLE001 - machine facts are best effort
        return "?"


def read_file(path, default="?"):
    try:
        with open(path) as f:
            return f.read().strip()
    except OSError:
        return default


def machine(out_dir):
    cpu = "?"
    for line in read_file("/proc/cpuinfo", "").splitlines():
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    mem_kib = 0
    for line in read_file("/proc/meminfo", "").splitlines():
        if line.startswith("MemTotal:"):
            mem_kib = int(line.split()[1])
    hyper = sh("lscpu | sed -n 's/^Hypervisor vendor: *//p'")
    dev = sh(f"findmnt -n -o SOURCE -T '{out_dir}'")
    blk = os.path.basename(dev) if dev.startswith("/dev/") else ""
    q = f"/sys/block/{blk}/queue" if blk else ""
    return {
        "CPU": f"{cpu}, {os.cpu_count()} logical CPUs" + (f" (KVM guest, hypervisor: {hyper})" if hyper else ""),
        "RAM": f"{mem_kib / 1024 / 1024:.1f} GiB" + (", no swap" if len(read_file("/proc/swaps", "").splitlines()) <= 1 else ""),
        "Kernel": sh("uname -r"),
        "Filesystem": sh(f"findmnt -n -o TARGET,SOURCE,FSTYPE,OPTIONS -T '{out_dir}'"),
        "Disk": (sh(f"df -h --output=source,size,used,avail '{out_dir}' | tail -n1") +
                 (f"; {blk}: virtio block device (vendor {read_file('/sys/block/' + blk + '/device/vendor')}), "
                  f"rotational={read_file(q + '/rotational')}, read_ahead_kb={read_file(q + '/read_ahead_kb')}, "
                  f"scheduler: {read_file(q + '/scheduler')}" if blk else "")),
        "Page cache": f"vm.dirty_ratio={read_file('/proc/sys/vm/dirty_ratio')}, "
                      f"vm.dirty_background_ratio={read_file('/proc/sys/vm/dirty_background_ratio')}",
        "dd": sh("dd --version | head -n1"),
        "Compiler": sh("c++ --version | head -n1"),
    }


def main():
    jsonl, out_md, size_gib, reps, drop, out_dir, command = sys.argv[1:8]
    rows = [json.loads(line) for line in open(jsonl) if line.strip()]
    by = {}
    for r in rows:
        by.setdefault(r["kind"], []).append(r)

    def speeds(kind):
        return [r["gb_per_s"] for r in by.get(kind, [])]

    def med(kind):
        v = speeds(kind)
        return statistics.median(v) if v else float("nan")

    def per_rep_ratio(kind, ref):
        a = {r["rep"]: r["gb_per_s"] for r in by.get(kind, [])}
        b = {r["rep"]: r["gb_per_s"] for r in by.get(ref, [])}
        return [a[k] / b[k] for k in sorted(a) if k in b]

    lines = []
    w = lines.append
    date = datetime.date.today().isoformat()
    commit = sh("git -C '%s' rev-parse --short HEAD" % os.path.dirname(os.path.abspath(jsonl)))
    w(f"# .ltm container I/O vs dd — {size_gib} GiB, {reps} repetitions")
    w("")
    w(f"Run on {date} (repository at commit {commit}, benchmark files uncommitted or later) with:")
    w("")
    w("```")
    w(command)
    w("```")
    w("")
    w("## Machine")
    w("")
    for k, v in machine(out_dir).items():
        w(f"- **{k}**: {v}")
    w(f"- **Benchmark directory**: `{out_dir}` (same filesystem as the repository)")
    w(f"- **Page cache before every read**: the file evicted with `ltm_io_bench evict` (fdatasync + "
      f"posix_fadvise DONTNEED, no root needed){' plus `echo 3 > /proc/sys/vm/drop_caches`' if drop == 'yes' else ''}; "
      f"mincore showed 0 bytes of the file resident before each timed read (the script stops otherwise).")
    busy = [r.get("busy_before_pct", 0) for r in rows if "busy_before_pct" in r]
    if busy:
        w(f"- **Other load**: before each timed command the script waited (≤ 30 s) for the machine to be "
          f"< 15% busy; busy % in the second before the commands: median {statistics.median(busy):.0f}, "
          f"max {max(busy)} (other work was running on this shared 2-CPU machine during the run).")
    w("")
    w("## Throughput (GB/s = file bytes / wall seconds of the whole process, 1 GB = 1e9 bytes)")
    w("")
    w("| what | command | median GB/s | min–max GB/s | median s |")
    w("| --- | --- | ---: | ---: | ---: |")
    table = [
        ("dd_write", "dd write, zeros", "`dd if=/dev/zero of=Z bs=8M count=N conv=fdatasync`"),
        ("dd_write_random", "dd write, random data", "`ltm_io_bench gen \\| dd of=F bs=8M iflag=fullblock conv=fdatasync`"),
        ("ltm_write", "**container write**", "`ltm_io_bench write C --bytes N` (random f32, raw, checksums on a 2nd thread, Finish() fdatasyncs)"),
        ("dd_read", "dd read (random dd file)", "`dd if=F of=/dev/null bs=8M`"),
        ("dd_read_container", "dd read of the container file", "`dd if=C of=/dev/null bs=8M`"),
        ("ltm_read", "**container read**", "`ltm_io_bench read C` (1 thread, ReadChunk, checksums verified, floats summed)"),
        ("ltm_read_prefetch4", "container read + caller prefetch", "`ltm_io_bench read C --prefetch 4` (same, plus WILLNEED on the next 4 chunks)"),
        ("ltm_read_noverify", "container read, no checksum", "`ltm_io_bench read C --no-verify`"),
    ]
    for kind, name, cmd in table:
        v = speeds(kind)
        if not v:
            continue
        secs = statistics.median(r["wall_seconds"] for r in by[kind])
        w(f"| {name} | {cmd} | {med(kind):.3f} | {min(v):.3f}–{max(v):.3f} | {secs:.2f} |")
    w("")
    w("## Ratios container / dd (target ≥ 0.80)")
    w("")
    w("| ratio | of medians | per repetition | target met |")
    w("| --- | ---: | --- | --- |")
    verdicts = {}
    for kind, ref, name in [
        ("ltm_write", "dd_write", "container write / dd write (zeros)"),
        ("ltm_write", "dd_write_random", "container write / dd write (random)"),
        ("ltm_read", "dd_read", "container read / dd read"),
        ("ltm_read", "dd_read_container", "container read / dd read of the container file"),
        ("ltm_read_prefetch4", "dd_read", "read + caller prefetch / dd read"),
        ("ltm_read_prefetch4", "dd_read_container", "read + caller prefetch / dd read of the container file"),
        ("ltm_read_noverify", "dd_read", "read, no checksum / dd read"),
    ]:
        if not speeds(kind) or not speeds(ref):
            continue
        ratio = med(kind) / med(ref)
        reps_r = ", ".join(f"{x:.2f}" for x in per_rep_ratio(kind, ref))
        ok = ratio >= 0.8
        verdicts[(kind, ref)] = ratio
        w(f"| {name} | {ratio:.2f} | {reps_r} | {'yes' if ok else 'NO: short of 0.80 by %.2f' % (0.8 - ratio)} |")
    w("")
    w("## Reader peak RSS (mmap, one chunk mapped at a time)")
    w("")
    rss_full = [r["tool"]["peak_rss_kib"] for r in by.get("ltm_read", [])]
    rss_small = [r["tool"]["peak_rss_kib"] for r in by.get("ltm_read_1gib", [])]
    w("| file | reader's own peak (max of VmHWM and sampled VmRSS) | /usr/bin/time %M |")
    w("| --- | ---: | ---: |")
    t_small = [r["maxrss_kib"] for r in rows if r["kind"] == "time_maxrss_1gib"]
    t_full = [r["maxrss_kib"] for r in rows if r["kind"] == "time_maxrss_full"]
    if rss_small:
        w(f"| 1 GiB | {max(rss_small) / 1024:.1f} MiB | {(str(round(max(t_small) / 1024, 1)) + ' MiB') if t_small else '—'} |")
    if rss_full:
        w(f"| {size_gib} GiB | {max(rss_full) / 1024:.1f} MiB (max over {len(rss_full)} runs) | "
          f"{(str(round(max(t_full) / 1024, 1)) + ' MiB') if t_full else '—'} |")
    other = []
    for kind in ("ltm_read_noverify", "ltm_read_prefetch4"):
        v = [r["tool"]["peak_rss_kib"] for r in by.get(kind, [])]
        if v:
            other.append(f"{kind}: {max(v) / 1024:.1f} MiB")
    wr = [r["tool"]["peak_rss_kib"] for r in by.get("ltm_write", [])]
    if wr:
        other.append(f"writer (4 pool buffers of one chunk): {max(wr) / 1024:.1f} MiB")
    if other:
        w("")
        w("Other peaks at full size: " + "; ".join(other) + ".")
    if rss_small and rss_full:
        a, b = max(rss_small), max(rss_full)
        indep = b <= a * 1.1 + 1024
        w("")
        w(f"RSS independent of file size: {'yes' if indep else 'NO'} "
          f"({a / 1024:.1f} MiB at 1 GiB vs {b / 1024:.1f} MiB at {size_gib} GiB).")
    w("")
    w(f"Raw per-run JSON: `bench/results/{os.path.basename(jsonl)}`.")
    with open(out_md, "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
