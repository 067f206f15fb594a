"""What every benchmark script records about where it ran."""
import json
import os
import platform
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def machine():
    """CPU model, logical CPUs, memory and kernel, one line."""
    cpu = "?"
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30
    nproc = subprocess.run(["nproc"], capture_output=True, text=True).stdout.strip()
    return f"{cpu}, nproc {nproc}, {mem:.1f} GiB, {platform.system()} {platform.release()}"


def git_describe():
    """The checkout's commit (with -dirty when it has changes)."""
    p = subprocess.run(["git", "-C", ROOT, "describe", "--always", "--dirty"], capture_output=True, text=True)
    return p.stdout.strip() if p.returncode == 0 else "?"


def run(ltbake, *args):
    """`ltbake ARGS` (any value, as text); its standard output. Exits naming the command and
    its output when it fails."""
    p = subprocess.run([ltbake, *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"ltbake {' '.join(map(str, args))}: exit {p.returncode}\n{p.stdout}{p.stderr}")
    return p.stdout


def run_bake(ltbake, recipe, workdir, *flags, env=None):
    """`ltbake run RECIPE --workdir WORKDIR FLAGS` from scratch (WORKDIR removed first); the
    stages of its run.json. Exits naming the command and its output when the bake fails."""
    subprocess.run(["rm", "-rf", workdir], check=True)
    p = subprocess.run([ltbake, "run", recipe, "--workdir", workdir, *flags], capture_output=True, text=True,
                       env=dict(os.environ, **(env or {})))
    if p.returncode != 0:
        sys.exit(f"ltbake run {recipe} {' '.join(flags)} failed ({p.returncode}):\n{p.stdout}{p.stderr}")
    with open(os.path.join(workdir, "run.json")) as f:
        return json.load(f)["stages"]


def write_report(path, lines):
    """Writes the lines (a Markdown report) to PATH and prints them."""
    text = "\n".join(lines) + "\n"
    with open(path, "w") as f:
        f.write(text)
    print(text)
