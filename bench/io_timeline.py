#!/usr/bin/python3
"""Runs a command and samples where its time goes, for the transpose benchmark.

  /usr/bin/python3 bench/io_timeline.py [--interval 0.5] [--out FILE.tsv] -- CMD ARGS...

Every --interval seconds it records, for the command's process (all threads):
  t            seconds since start
  rchar_gb     bytes passed to read/pread so far (/proc/PID/io rchar; page-cache hits included)
  wchar_gb     bytes passed to write/pwrite so far (wchar)
  disk_r_gb    bytes it caused to be read from the disk (read_bytes)
  dirty_mb     Dirty + Writeback in /proc/meminfo (data not yet on disk, whole machine)
  cpu_user/cpu_sys  its CPU seconds so far (all threads)
  main_cpu     CPU seconds of the main thread (ltbake: checksum pass, panel fills)
  top_thread_cpu  CPU seconds of the busiest other thread alive (ltbake: the writer)
  threads      threads alive
  mach_busy    whole machine CPU busy % over the interval (iowait counted as idle)
  io_some      /proc/pressure/io "some" share of the interval, %
The table goes to --out (TSV) and a one-line JSON summary (wall, peak RSS from
wait4's rusage, final counters) to stdout. The command's own stdout/stderr pass through
to this script's stderr.
"""
import argparse
import json
import os
import subprocess
import sys
import time


def read_io(pid):
    d = {}
    try:
        with open(f"/proc/{pid}/io") as f:
            for line in f:
                k, v = line.split(":")
                d[k] = int(v)
    except OSError:
        pass
    return d


def meminfo():
    d = {}
    with open("/proc/meminfo") as f:
        for line in f:
            k, v = line.split(":")
            d[k] = int(v.split()[0])
    return d


def thread_cpu(pid):
    """{tid: cpu seconds} for every thread of pid."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            out[int(tid)] = (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError):
            pass
    return out


def proc_cpu(pid):
    tick = os.sysconf("SC_CLK_TCK")
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return int(fields[11]) / tick, int(fields[12]) / tick
    except (OSError, IndexError):
        return None


def machine_stat():
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    idle = v[3] + v[4]
    return sum(v[:8]) - idle, idle


def io_some_us():
    try:
        with open("/proc/pressure/io") as f:
            for line in f:
                if line.startswith("some"):
                    return int(line.split("total=")[1])
    except OSError:
        return None
    return None


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--interval", type=float, default=0.5)
    p.add_argument("--out", default=None)
    p.add_argument("cmd", nargs=argparse.REMAINDER)
    a = p.parse_args()
    cmd = a.cmd[1:] if a.cmd and a.cmd[0] == "--" else a.cmd
    if not cmd:
        p.error("no command")
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=sys.stderr, stderr=sys.stderr)
    rows = []
    thread_max = {}
    prev_busy, prev_idle = machine_stat()
    prev_io = io_some_us()
    prev_t = t0
    last = {}
    rusage = None
    while True:
        # Poll without reaping, so /proc/PID stays readable until the end.
        try:
            pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
        except ChildProcessError:
            break
        if pid == proc.pid:
            rusage = ru
            proc.returncode = os.waitstatus_to_exitcode(status)
            break
        now = time.monotonic()
        io = read_io(proc.pid)
        mi = meminfo()
        cpu = proc_cpu(proc.pid)
        threads = thread_cpu(proc.pid)
        for tid, c in threads.items():
            thread_max[tid] = max(thread_max.get(tid, 0), c)
        busy, idle = machine_stat()
        iop = io_some_us()
        dt = max(1e-9, now - prev_t)
        others = [c for tid, c in threads.items() if tid != proc.pid]
        if io and cpu:
            last = {
                "t": round(now - t0, 2),
                "rchar_gb": round(io.get("rchar", 0) / 1e9, 3),
                "wchar_gb": round(io.get("wchar", 0) / 1e9, 3),
                "disk_r_gb": round(io.get("read_bytes", 0) / 1e9, 3),
                "dirty_mb": (mi.get("Dirty", 0) + mi.get("Writeback", 0)) // 1024,
                "cpu_user": round(cpu[0], 2),
                "cpu_sys": round(cpu[1], 2),
                "main_cpu": round(threads.get(proc.pid, 0), 2),
                "top_thread_cpu": round(max(others) if others else 0, 2),
                "threads": len(threads),
                "mach_busy": round(100 * (busy - prev_busy) / max(1, (busy - prev_busy) + (idle - prev_idle))),
                "io_some": round((iop - prev_io) / 1e4 / dt) if iop is not None and prev_io is not None else None,
            }
            rows.append(last)
        prev_busy, prev_idle, prev_io, prev_t = busy, idle, iop, now
        time.sleep(a.interval)
    wall = time.monotonic() - t0
    if a.out:
        with open(a.out, "w") as f:
            if rows:
                f.write("\t".join(rows[0].keys()) + "\n")
                for r in rows:
                    f.write("\t".join(str(v) for v in r.values()) + "\n")
    summary = {"cmd": cmd, "exit": proc.returncode, "wall_seconds": wall,
               "peak_rss_kib": rusage.ru_maxrss if rusage else None,
               "user_seconds": rusage.ru_utime if rusage else None,
               "sys_seconds": rusage.ru_stime if rusage else None,
               "thread_cpu_max_seconds": sorted(thread_max.values(), reverse=True)[:4], "last_sample": last}
    print(json.dumps(summary))
    sys.exit(proc.returncode or 0)


if __name__ == "__main__":
    main()
