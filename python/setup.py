"""`pip install ./python`: the ltbake Python module (docs/PYTHON.md), offline.

The extension is the CMake target `ltb_python` of this checkout (the same C++ libraries as
the `ltbake` command), so installing builds it there first:
  - LTBAKE_BUILD_DIR, when set, is the build tree to use (configured if it is not yet);
  - else <checkout>/build, as `make build` leaves it.
Nothing is downloaded: setuptools, pip and NumPy are Debian's (python3-setuptools, python3-pip,
python3-venv, python3-numpy; scripts/setup.sh installs them). There is no pyproject.toml on
purpose: its build isolation would fetch setuptools from an index. In a virtual environment,
create it with --system-site-packages so that it sees Debian's NumPy:

    /usr/bin/python3 -m venv --system-site-packages ~/venvs/ltb
    ~/venvs/ltb/bin/pip install ./python
    ~/venvs/ltb/bin/python -c "import ltbake; print(ltbake.__version__)"
"""
import glob
import os
import re
import shutil
import subprocess
import sys

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.dist import Distribution

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def version():
    with open(os.path.join(ROOT, "CMakeLists.txt")) as f:
        m = re.search(r"project\(ltbake VERSION ([0-9.]+)", f.read())
    if not m:
        raise SystemExit(f"{ROOT}/CMakeLists.txt: no 'project(ltbake VERSION x.y.z)' line")
    return m.group(1)


class BuildWithCMake(build_py):
    """build_py, plus the extension built by CMake and copied beside __init__.py."""

    def run(self):
        super().run()
        build = os.path.abspath(os.environ.get("LTBAKE_BUILD_DIR") or os.path.join(ROOT, "build"))
        tag = f"cpython-{sys.version_info.major}{sys.version_info.minor}"
        if not os.path.exists(os.path.join(build, "CMakeCache.txt")):
            print(f"ltbake: configuring {build} (a Release build of the module; a few minutes)", flush=True)
            subprocess.check_call(["cmake", "-S", ROOT, "-B", build, "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
                                   f"-DPython_EXECUTABLE={os.path.realpath(sys.executable)}"])
        subprocess.check_call(["cmake", "--build", build, "--target", "ltb_python"])
        found = glob.glob(os.path.join(build, "python", "ltbake", "_ltbake.*.so"))
        ours = [p for p in found if tag in os.path.basename(p)]
        if not ours:
            raise SystemExit(
                f"ltbake: {build} holds the extension for {[os.path.basename(p) for p in found]}, not for this "
                f"Python ({sys.version.split()[0]}, {tag}). Install with the Python the build was configured for "
                f"(Debian's: /usr/bin/python3 -m pip install ./python), or point LTBAKE_BUILD_DIR at a new "
                f"directory to configure one for this Python.")
        dest = os.path.join(self.build_lib, "ltbake")
        os.makedirs(dest, exist_ok=True)
        shutil.copy2(ours[0], dest)


class BinaryDistribution(Distribution):
    """The package carries a compiled extension: a platform wheel, not a pure one."""

    def has_ext_modules(self):
        return True


setup(
    name="ltbake",
    version=version(),
    description="light transport containers (.ltm) as NumPy arrays, and relighting",
    packages=["ltbake"],
    package_dir={"ltbake": "ltbake"},
    cmdclass={"build_py": BuildWithCMake},
    distclass=BinaryDistribution,
    python_requires=">=3.9",
    zip_safe=False,
)
