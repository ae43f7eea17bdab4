"""Build parallel_gpc._native into src/parallel_gpc/ for a source checkout used with PYTHONPATH=src.

``pip install .`` is the normal route (it builds the same CMake project in an isolated
environment). This script is for development: it configures CMakeLists.txt with the running
Python (which must have pin, nanobind and cmeel-eigen installed) into build/native-dev, builds it
and copies the module next to the Python sources. Re-run it after editing native/src.

    python native/build_inplace.py [--debug]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--debug", action="store_true", help="build type Debug instead of Release")
    args = parser.parse_args()
    build = ROOT / "build" / "native-dev"
    build.mkdir(parents=True, exist_ok=True)
    gen = ["-G", "Ninja"] if shutil.which("ninja") else []
    subprocess.run(["cmake", "-S", str(ROOT), "-B", str(build), *gen,
                    f"-DPython_EXECUTABLE={sys.executable}",
                    f"-DCMAKE_BUILD_TYPE={'Debug' if args.debug else 'Release'}"], check=True)
    start = time.perf_counter()
    subprocess.run(["cmake", "--build", str(build), "-j", "2"], check=True)
    print(f"built in {(time.perf_counter() - start) / 60:.1f} min (wall; docs/performance.md#building-the-core)")
    built = sorted(build.glob("_native*.so"))
    if not built:
        sys.exit(f"no _native*.so in {build}")
    target = ROOT / "src" / "parallel_gpc" / built[0].name
    shutil.copy2(built[0], target)
    print(f"copied {built[0].name} -> {target}")


if __name__ == "__main__":
    main()
