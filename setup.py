# SPDX-License-Identifier: BSD-3-Clause
"""Builds the extension module iwlomap._iwlomap with CMake for `pip install .` (see pyproject.toml)."""

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent


def cmake_version():
    text = (ROOT / "CMakeLists.txt").read_text()
    return re.search(r"project\(iwlomap VERSION ([0-9.]+)", text).group(1)


class CMakeExtension(Extension):
    def __init__(self):
        super().__init__("iwlomap._iwlomap", sources=[])


class CMakeBuild(build_ext):
    def build_extension(self, ext):
        if shutil.which("cmake") is None:
            raise RuntimeError("iwlomap: building the Python package needs cmake (bash scripts/setup.sh installs it)")
        build = Path(os.environ.get("IWLOMAP_PIP_BUILD_DIR", ROOT / "build-python")).resolve()
        args = [
            "-S", str(ROOT), "-B", str(build),
            "-DCMAKE_BUILD_TYPE=Release",
            "-DIWLOMAP_WITH_PYTHON=ON",
            f"-DPython3_EXECUTABLE={sys.executable}",
            # Only what the package needs: no tests, tool, examples, benchmarks, PCL filter or MPI.
            "-DIWLOMAP_BUILD_TESTS=OFF", "-DIWLOMAP_BUILD_SAMPLES=OFF", "-DIWLOMAP_BUILD_EXAMPLES=OFF",
            "-DIWLOMAP_BUILD_BENCHMARKS=OFF", "-DIWLOMAP_WITH_FILTERS=OFF", "-DIWLOMAP_WITH_MPI=OFF",
        ]
        if shutil.which("ccache"):
            args += ["-DCMAKE_C_COMPILER_LAUNCHER=ccache", "-DCMAKE_CXX_COMPILER_LAUNCHER=ccache"]
        args += shlex.split(os.environ.get("IWLOMAP_CMAKE_ARGS", ""))
        jobs = os.environ.get("CMAKE_BUILD_PARALLEL_LEVEL", str(os.cpu_count() or 1))
        subprocess.run(["cmake", *args], check=True)
        subprocess.run(["cmake", "--build", str(build), "--target", "iwlomap_python", "-j", jobs], check=True)
        built = sorted((build / "python" / "iwlomap").glob("_iwlomap*.so"))
        if len(built) != 1:
            raise RuntimeError(f"iwlomap: expected one extension module in {build}/python/iwlomap, found {built}")
        target = Path(self.get_ext_fullpath(ext.name))
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(built[0], target)


version = cmake_version()
setup(version=version, ext_modules=[CMakeExtension()], cmdclass={"build_ext": CMakeBuild})
