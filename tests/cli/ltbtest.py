"""Shared harness for the CLI tests: run ltbake, record checks, print the summary line
('N passed, M failed') that CI reads, and exit non-zero on any failure."""
import os
import subprocess
import sys
import time

LTBAKE = sys.argv[1] if len(sys.argv) > 1 else "ltbake"
failures = []
checks = 0

# The heavy scripts' scale knob: LTB_TEST_SCALE (default 1, the full suite) multiplies their
# repetition counts (kills in the storms, kill-and-resume trials); `make test` sets it for
# CI (tests/README.md). A count never drops below its `minimum`, so every case still runs.
SCALE = float(os.environ.get("LTB_TEST_SCALE", "1") or 1)


def scaled(n, minimum=1):
    """n repetitions at full scale, scaled by LTB_TEST_SCALE, at least `minimum`."""
    return max(minimum, int(round(n * SCALE)))


def check(cond, what):
    """Records one check; `what` says what went wrong when cond is false."""
    global checks
    checks += 1
    if not cond:
        failures.append(what)


def run(*args, expect=0, timeout=900):
    """Runs `ltbake ARGS`; an exit code other than `expect` (None: any) is a failure."""
    start = time.monotonic()
    p = subprocess.run([LTBAKE, *map(str, args)], capture_output=True, text=True, timeout=timeout)
    if os.environ.get("LTB_TEST_TIMES"):  # where a suite's time goes (tests/README.md)
        print(f"[{time.monotonic() - start:7.2f} s] ltbake {' '.join(map(str, args))}", file=sys.stderr)
    if expect is not None and p.returncode != expect:
        failures.append(f"ltbake {' '.join(map(str, args))}: exit {p.returncode}, expected {expect}\n{p.stdout}{p.stderr}")
    return p


def write(path, text):
    """Writes a small text file (a recipe, a scene) and returns its path."""
    with open(path, "w") as f:
        f.write(text)
    return path


def run_report(workdir):
    """The run.json of an `ltbake run` work directory."""
    import json
    import os
    with open(os.path.join(workdir, "run.json")) as f:
        return json.load(f)


def finish():
    for f in failures:
        print(f)
    print(f"{checks - len(failures)} passed, {len(failures)} failed")
    sys.exit(1 if failures else 0)


def kill_storm(args, out, kills, max_delay, seed):
    """Runs `ltbake ARGS` `kills` times, SIGKILLing it after a random delay in
    [0, max_delay); after each kill the partial `out` (if any) must verify as intact."""
    import json
    import os
    import random
    import signal
    import time
    rnd = random.Random(seed)
    for k in range(kills):
        p = subprocess.Popen([LTBAKE, *map(str, args)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rnd.uniform(0.0, max_delay))
        p.send_signal(signal.SIGKILL)
        p.wait()
        if os.path.exists(out):
            v = json.loads(run("verify", "--allow-incomplete", "--json", out).stdout)[0]
            check(v["ok"], f"kill {k}: partial output does not verify: {v}")


def side_table(ltm, name):
    """A side table (row blocks: mask, position, normal, ...) read straight from the file's
    bytes at the offsets `inspect --chunks` lists, as NumPy: raw chunks as they are, zstd
    ones through the zstd command-line tool (Debian `zstd`, an independent decoder)."""
    import json
    import numpy as np
    info = json.loads(run("inspect", ltm, "--json", "--chunks").stdout)
    arr = next(a for a in info["arrays"] if a["name"] == name)
    rows, cols, block = arr["shape"][0], arr["shape"][1], arr["block"]
    dtype = {"f32": np.float32, "f64": np.float64, "u8": np.uint8, "u32": np.uint32, "u64": np.uint64}[arr["dtype"]]
    raw = open(ltm, "rb").read()
    out = np.zeros((rows, cols), dtype)
    for c in info["chunk_list"]:
        if c["array"] != name or c["encoding"] == "zero":
            continue
        r0 = c["index"] * block
        if c["encoding"] == "zstd":
            payload = raw[c["offset"] + 64:c["offset"] + 64 + c["stored_bytes"]]
            data = subprocess.run(["zstd", "-d", "-c", "-q"], input=payload, capture_output=True, check=True).stdout
            assert len(data) == c["decoded_bytes"], f"{ltm}: zstd chunk {c['index']} of {name} decodes to {len(data)} bytes"
            v = np.frombuffer(data, dtype)
        else:
            assert c["encoding"] == "raw", f"{ltm}: {name} chunk {c['index']} is {c['encoding']}"
            v = np.frombuffer(raw, dtype, count=c["decoded_bytes"] // np.dtype(dtype).itemsize, offset=c["offset"] + 64)
        out[r0:r0 + len(v) // cols] = v.reshape(-1, cols)
    return out


def haar_faces(L, R):
    """Per-face orthonormal 2D Haar (PyWavelets, periodization, full depth, Mallat layout) of
    a 6R² × 3 cubemap, in float64: the lighting basis of a Haar row-transformed bake."""
    import numpy as np
    import pywt
    out = np.zeros(L.shape, np.float64)
    for f in range(6):
        for c in range(3):
            face = L[f * R * R:(f + 1) * R * R, c].reshape(R, R).astype(np.float64)
            arr, _ = pywt.coeffs_to_array(pywt.wavedec2(face, "haar", mode="periodization", level=int(np.log2(R))))
            out[f * R * R:(f + 1) * R * R, c] = arr.reshape(-1)
    return out
