"""Harness for the hostile-input suites: run ltbake on a small hand-made file and check
that it fails the way a user can act on.

Every case asserts
  - the exit code (1 = the input is bad or the work failed, 2 = the command line is bad),
    never a signal (a crash, an assertion, an uncaught exception: exit 134/139 or < 0);
  - that stderr names the file and the field (the strings given in `names`);
  - a time bound (a hang detector, generous: seconds for a file of bytes);
  - a peak-memory bound: 64 MiB plus what the file's size justifies, from the child's
    own ru_maxrss (wait4), in the release tree; under the sanitizers (LTB_SANITIZED=1 in
    the environment, set by the ASan tree) the shadow memory makes RSS meaningless and
    only the other checks apply.
"""
import os
import signal
import subprocess
import sys
import time

import ltbtest
from ltbtest import check

SANITIZED = os.environ.get("LTB_SANITIZED", "") not in ("", "0")
BASE_MIB = 64
# The CPU time (user + system) of the last run_hostile child: for comparing the cost of two
# inputs in one run, which other processes on the machine barely disturb (wall time they do).
last_cpu_seconds = 0.0


def run_hostile(args, names=(), expect=(1,), time_limit=60.0, extra_mib=0.0, what=None, cwd=None):
    """Runs `ltbake ARGS`; returns (exit code, stderr). `names`: strings stderr must
    contain (file, field, value); `expect`: allowed exit codes; `extra_mib`: memory the
    input justifies beyond the 64 MiB base (e.g. its own size)."""
    label = what or "ltbake " + " ".join(map(str, args))
    start = time.monotonic()
    p = subprocess.Popen([ltbtest.LTBAKE, *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         stdin=subprocess.DEVNULL, cwd=cwd)
    # Drain the pipes in the background so a chatty child cannot block; wait4 gives rusage.
    import threading
    out, err = [], []
    t1 = threading.Thread(target=lambda: out.append(p.stdout.read()))
    t2 = threading.Thread(target=lambda: err.append(p.stderr.read()))
    t1.start()
    t2.start()
    status = None
    rusage = None
    while True:
        pid, st, ru = os.wait4(p.pid, os.WNOHANG)
        if pid == p.pid:
            status, rusage = st, ru
            break
        if time.monotonic() - start > time_limit:
            p.kill()
            _, status, rusage = os.wait4(p.pid, 0)
            break
        time.sleep(0.01)
    p.returncode = os.waitstatus_to_exitcode(status)
    elapsed = time.monotonic() - start
    if os.environ.get("LTB_TEST_TIMES"):  # where a suite's time goes (tests/README.md)
        print(f"[{elapsed:7.2f} s] {label}", file=sys.stderr)
    global last_cpu_seconds
    last_cpu_seconds = rusage.ru_utime + rusage.ru_stime
    t1.join()
    t2.join()
    stderr = err[0].decode(errors="replace") if err else ""
    code = p.returncode
    check(elapsed <= time_limit, f"{label}: still running after {time_limit:.0f} s (hang); killed")
    check(code >= 0 and code not in (134, 136, 139), f"{label}: died of a signal or abort (exit {code})\n{stderr}")
    check(code in expect, f"{label}: exit {code}, expected one of {list(expect)}\n{stderr}")
    for n in names:
        check(str(n) in stderr, f"{label}: the message does not name {n!r}:\n{stderr}")
    if not SANITIZED:
        peak_mib = rusage.ru_maxrss / 1024.0  # Linux: KiB
        limit = BASE_MIB + extra_mib
        check(peak_mib <= limit, f"{label}: peak memory {peak_mib:.1f} MiB > {limit:.1f} MiB")
    return code, stderr


def interrupt_while_running(args, ready, sig=signal.SIGTERM, time_limit=60.0, what=None):
    """Starts `ltbake ARGS`, waits until `ready()` is true (a condition, never a fixed
    time), sends `sig` and checks the process ends within `time_limit` with 130/143 or a
    clear error (1), not by being killed. Returns (exit code, stderr)."""
    label = what or "ltbake " + " ".join(map(str, args))
    p = subprocess.Popen([ltbtest.LTBAKE, *map(str, args)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         stdin=subprocess.DEVNULL)
    start = time.monotonic()
    while not ready() and p.poll() is None and time.monotonic() - start < time_limit:
        time.sleep(0.01)
    p.send_signal(sig)
    try:
        _, stderr = p.communicate(timeout=time_limit)
    except subprocess.TimeoutExpired:
        p.kill()
        _, stderr = p.communicate()
        check(False, f"{label}: ignored {signal.Signals(sig).name} for {time_limit:.0f} s")
        return None, stderr.decode(errors="replace")
    want = 143 if sig == signal.SIGTERM else 130
    check(p.returncode in (want, 1), f"{label}: exit {p.returncode} after {signal.Signals(sig).name}, "
          f"expected {want} (or 1)\n{stderr.decode(errors='replace')}")
    return p.returncode, stderr.decode(errors="replace")


def scene_for(d, name, mesh, extra=""):
    """A small image-mode scene around one mesh object (the mesh path relative to d)."""
    return ltbtest.write(os.path.join(d, name + ".toml"), f"""[camera]
eye = [0.5, -3.0, 2.0]
target = [0.5, 0.5, 0.0]
width = 4
height = 4
[sampling]
cube_res = 1
spp = 1
[[object]]
name = "m"
type = "mesh"
file = "{mesh}"
{extra}""")
