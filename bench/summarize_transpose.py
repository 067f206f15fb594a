#!/usr/bin/python3
"""Summarizes bench/results/transpose.jsonl (bench/run_transpose.sh) into a Markdown report.

  summarize_transpose.py JSONL OUT.md [COMMAND]

Medians over repetitions, ratios of medians and per repetition, peak RSS, the bytes
ltbake reports, and a mechanical check of the three targets (the README gives the
reading of them).
"""
import json
import statistics
import sys

GIB = 1 << 30


def main():
    path, out_md = sys.argv[1], sys.argv[2]
    command = sys.argv[3] if len(sys.argv) > 3 else ""
    lines = [json.loads(x) for x in open(path) if x.strip()]
    setup = next((d for d in lines if d["kind"] == "setup"), {})
    runs = {}
    for d in lines:
        if "wall_seconds" in d:
            runs.setdefault(d["kind"], []).append(d)

    def times(kind):
        return [d["wall_seconds"] for d in runs.get(kind, [])]

    def med(kind):
        t = times(kind)
        return statistics.median(t) if t else None

    payload = setup.get("payload_bytes", 0)
    # dd read + dd write of the same repetition.
    rw = {}
    for d in runs.get("dd_read", []) + runs.get("dd_write", []):
        rw.setdefault(d["rep"], []).append(d["wall_seconds"])
    rw_sums = [sum(v) for v in rw.values() if len(v) == 2]

    rows = []  # (what, n, median s, min-max s, GB/s, x dd copy, peak RSS)
    floor = med("dd_copy")
    floor_rw = statistics.median(rw_sums) if rw_sums else None

    def add(label, kind, values=None):
        t = values if values is not None else times(kind)
        if not t:
            return
        m = statistics.median(t)
        rss = [d.get("peak_rss_kib") for d in runs.get(kind, []) if d.get("peak_rss_kib")]
        rows.append((label, len(t), m, min(t), max(t), payload / m / 1e9,
                     m / floor if floor else None, max(rss) if rss else None))

    add("**ltbake transpose** (checksum pass on, output with O_DIRECT)", "transpose")
    add("ltbake transpose --no-direct-io (output through the page cache)", "transpose_buffered")
    add("ltbake transpose --no-verify-input", "transpose_no_verify")
    add("dd copy in.ltm -> file, conv=fdatasync (**floor**)", "dd_copy")
    add("dd read in.ltm + dd write zeros (same rep)", None, rw_sums)
    add("  dd read in.ltm", "dd_read")
    add("  dd write zeros, conv=fdatasync", "dd_write")
    add("dd copy, iflag=direct oflag=direct (reference)", "dd_copy_direct")
    add("h5py, 1 GiB chunk cache per file, band.T", "h5py")
    add("h5py, 1 GiB chunk cache per file, sliced transpose", "h5py_sliced")
    add("h5py, 256 MiB chunk cache per file, sliced transpose", "h5py_sliced_cache256m")

    t_med = med("transpose")
    h5_kinds = [k for k in ("h5py", "h5py_sliced") if med(k)]
    h5_best = min(h5_kinds, key=med) if h5_kinds else None  # the target is judged on the faster
    h5 = med(h5_best) if h5_best else None
    out = []
    out.append("# `ltbake transpose` benchmark results\n")
    out.append(f"Command: `{command}`  ")
    out.append(f"Date: {setup.get('date', '?')}; matrix {setup.get('rows')} x {setup.get('cols')} f32 "
               f"({payload} bytes payload); CPU {setup.get('cpu')}, {setup.get('nproc')} vCPUs, "
               f"{setup.get('mem_kib', 0) / 1024 / 1024:.1f} GiB RAM, kernel {setup.get('kernel')}.\n")
    out.append("| what | n | median s | min–max s | GB/s (median) | × dd copy | peak RSS |")
    out.append("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for label, n, m, lo, hi, gbs, ratio, rss in rows:
        out.append(f"| {label} | {n} | {m:.2f} | {lo:.2f}–{hi:.2f} | {gbs:.3f} | "
                   f"{'' if ratio is None else f'{ratio:.2f}'} | "
                   f"{'' if rss is None else f'{rss / 1024:.0f} MiB'} |")
    out.append("")

    # Per repetition pairs.
    by_rep = {}
    for k in ("transpose", "dd_copy"):
        for d in runs.get(k, []):
            by_rep.setdefault(d["rep"], {})[k] = d["wall_seconds"]
    pairs = [v["transpose"] / v["dd_copy"] for _, v in sorted(by_rep.items()) if len(v) == 2]
    pairs_rw = [by_rep[r]["transpose"] / sum(rw[r]) for r in sorted(by_rep)
                if "transpose" in by_rep[r] and len(rw.get(r, [])) == 2]
    out.append("| ratio | of medians | per repetition |")
    out.append("| --- | ---: | --- |")
    if t_med and floor:
        out.append(f"| transpose / dd copy | **{t_med / floor:.2f}** | {', '.join(f'{x:.2f}' for x in pairs)} |")
    if t_med and floor_rw:
        out.append(f"| transpose / (dd read + dd write) | {t_med / floor_rw:.2f} | "
                   f"{', '.join(f'{x:.2f}' for x in pairs_rw)} |")
    bu = med("transpose_buffered")
    if bu and t_med:
        by_rep_b = {d["rep"]: d["wall_seconds"] for d in runs.get("transpose_buffered", [])}
        per = [by_rep_b[r] / by_rep[r]["transpose"] for r in sorted(by_rep)
               if r in by_rep_b and "transpose" in by_rep[r]]
        out.append(f"| transpose --no-direct-io / transpose | {bu / t_med:.2f} | {', '.join(f'{x:.2f}' for x in per)} |")
    nv = med("transpose_no_verify")
    if nv and floor:
        out.append(f"| transpose --no-verify-input / dd copy | {nv / floor:.2f} | (1 run) |")
    for k, label in (("h5py", "h5py band.T (1 GiB cache)"), ("h5py_sliced", "h5py sliced (1 GiB cache)"),
                     ("h5py_sliced_cache256m", "h5py sliced (256 MiB cache)")):
        if med(k) and t_med:
            bold = "**" if k == h5_best else ""
            out.append(f"| {label} / transpose | {bold}{med(k) / t_med:.2f}{bold} | "
                       f"{', '.join(f'{x / t_med:.2f}' for x in times(k))} (each h5py run / median transpose) |")
    out.append("")

    tr = runs.get("transpose", [])
    if tr:
        d = tr[0]
        out.append(f"ltbake reports (every run): {d.get('panels')} panels of up to {d.get('panel_cols')} columns; "
                   f"read {d.get('bytes_read')} + verified {d.get('bytes_verified')} bytes, wrote "
                   f"{d.get('bytes_written')} ({d.get('bytes_direct', 0)} with O_DIRECT); --no-verify-input: read "
                   f"{runs.get('transpose_no_verify', [{}])[0].get('bytes_read')} + verified "
                   f"{runs.get('transpose_no_verify', [{}])[0].get('bytes_verified')}.\n")
        us = [x["user_seconds"] for x in tr]
        ss = [x["sys_seconds"] for x in tr]
        out.append(f"CPU time of the transposes: user {statistics.median(us):.1f} s, sys {statistics.median(ss):.1f} s "
                   f"(medians; sys range {min(ss):.1f}–{max(ss):.1f} s).\n")
        tb = [x for x in runs.get("transpose_buffered", []) if "user_seconds" in x]
        if tb:
            out.append(f"... and with --no-direct-io: user {statistics.median([x['user_seconds'] for x in tb]):.1f} s, "
                       f"sys {statistics.median([x['sys_seconds'] for x in tb]):.1f} s (sys range "
                       f"{min(x['sys_seconds'] for x in tb):.1f}–{max(x['sys_seconds'] for x in tb):.1f} s).\n")
    h5runs = runs.get("h5py", []) + runs.get("h5py_sliced", []) + runs.get("h5py_sliced_cache256m", [])
    if h5runs:
        out.append("h5py phases (s): " + "; ".join(
            f"{d['kind']} rep {d['rep']}: total {d['tool']['seconds']:.1f} = read {d['tool']['read_seconds']:.1f} + "
            f"numpy transpose {d['tool']['transpose_seconds']:.1f} + write {d['tool']['write_seconds']:.1f} + "
            f"close {d['tool']['close_seconds']:.1f} + fsync {d['tool']['fsync_seconds']:.1f}"
            for d in h5runs if "tool" in d) + ".\n")
    checks = [d for d in lines if d["kind"].startswith("check")]
    if checks:
        out.append("Correctness: " + "; ".join(f"{d['kind']}: ok={d['result'].get('ok')}" for d in checks) + ".\n")

    out.append("Targets (mechanical check; see bench/README.md for the reading):\n")
    if t_med and floor:
        r = t_med / floor
        out.append(f"- within 1.5× of the dd floor: {'met' if r <= 1.5 else 'missed'} ({r:.2f}× dd copy)")
    if t_med and h5:
        r = h5 / t_med
        out.append(f"- ≥ 3× faster than h5py: {'met' if r >= 3 else 'missed'} ({r:.2f}× the faster h5py variant, "
                   f"{h5_best}; " + ", ".join(f"{med(k) / t_med:.2f}× {k}" for k in h5_kinds) + ")")
    rss = [d["peak_rss_kib"] for d in tr + runs.get("transpose_no_verify", []) if d.get("peak_rss_kib")]
    if rss:
        m = max(rss)
        out.append(f"- peak RSS ≤ 1.2 GiB: {'met' if m <= 1.2 * GIB / 1024 else 'missed'} "
                   f"(max {m} KiB = {m / 1024 / 1024:.3f} GiB)")
    out.append("")
    out.append("Busy % of the machine before each timed command: " +
               ", ".join(f"{d['kind']}#{d['rep']}={d['busy_before_pct']}" for d in lines if "busy_before_pct" in d
                         and "wall_seconds" in d) + ".")
    with open(out_md, "w") as f:
        f.write("\n".join(out) + "\n")
    print("\n".join(out))


if __name__ == "__main__":
    main()
