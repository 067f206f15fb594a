"""`pip install ./python` into a fresh virtual environment, offline, and docs/PYTHON.md's
"In five lines" examples run as they are with the installed package."""
import os
import re
import subprocess

from conftest import REPO

DOC = os.path.join(REPO, "docs", "PYTHON.md")


def examples():
    """The ```python blocks that follow an <!-- example --> line in docs/PYTHON.md."""
    text = open(DOC).read()
    return re.findall(r"<!-- example -->\n```python\n(.*?)```", text, re.S)


def test_pip_install_offline_runs_the_doc_examples(bake, tmp_path):
    blocks = examples()
    assert len(blocks) >= 4, f"{DOC}: expected the four examples of 'In five lines', found {len(blocks)}"
    venv = tmp_path / "venv"
    subprocess.run(["/usr/bin/python3", "-m", "venv", "--system-site-packages", str(venv)], check=True)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # the installed copy, not the build tree's
    env["LTBAKE_BUILD_DIR"] = os.environ.get("LTB_BUILD_DIR", os.path.join(REPO, "build"))
    env["PIP_NO_INDEX"] = "1"  # offline: an index would be a network fetch
    p = subprocess.run([str(venv / "bin" / "pip"), "install", "--no-index", "--no-cache-dir", os.path.join(REPO, "python")],
                       env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, f"pip install ./python failed:\n{p.stdout}\n{p.stderr}"
    py = str(venv / "bin" / "python")
    where = subprocess.run([py, "-c", "import ltbake; print(ltbake.__file__)"], env=env, cwd=tmp_path,
                           capture_output=True, text=True)
    assert where.returncode == 0 and where.stdout.startswith(str(venv)), f"import ltbake: {where.stdout}{where.stderr}"
    work = tmp_path / "work"
    work.mkdir()
    for name in ("rows.ltm", "final.ltm", "env.npy"):
        os.symlink(bake["P"](name), work / name)
    for i, code in enumerate(blocks):
        r = subprocess.run([py, "-c", code], env=env, cwd=work, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, f"docs/PYTHON.md example {i + 1} failed:\n{code}\n{r.stdout}{r.stderr}"
        assert r.stdout.strip() or "assert" in code, f"example {i + 1} printed nothing:\n{code}"
    assert (work / "m.ltm").exists()
