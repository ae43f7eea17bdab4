"""Packaging facts that must stay true: every subpackage is shipped, the licence file matches the
metadata, the package is typed, requires-python holds, no docstring cites a missing document."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "parallel_gpc"
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def test_the_wheel_ships_the_whole_package_folder_and_the_robots():
    """scikit-build-core copies src/parallel_gpc (every subpackage, py.typed); CMake installs the
    embedded robots as parallel_gpc/urdf and the compiled core as parallel_gpc/_native."""
    assert PROJECT["build-system"]["build-backend"] == "scikit_build_core.build"
    assert PROJECT["tool"]["scikit-build"]["wheel"]["packages"] == ["src/parallel_gpc"]
    cmake = (ROOT / "CMakeLists.txt").read_text(encoding="utf-8")
    assert "install(DIRECTORY urdf/ DESTINATION parallel_gpc/urdf" in cmake
    assert "install(TARGETS _native LIBRARY DESTINATION parallel_gpc)" in cmake
    assert (ROOT / "urdf" / "__init__.py").is_file()


def test_license_file_matches_the_metadata():
    assert PROJECT["project"]["license"] == {"text": "BSD-3-Clause"}
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert text.startswith("BSD 3-Clause License") and "Neither the name of the copyright holder" in text


def test_typed_marker_is_shipped():
    assert (PACKAGE / "py.typed").is_file()


def test_requires_python_is_true():
    """The package imports tomllib (3.11+): the declared floor must be 3.11."""
    assert PROJECT["project"]["requires-python"] == ">=3.11"
    assert sys.version_info >= (3, 11)


def test_no_docstring_cites_the_unshipped_design_document():
    cited = [str(p.relative_to(ROOT)) for p in PACKAGE.rglob("*.py") if "DESIGN §" in p.read_text(encoding="utf-8")]
    assert cited == []


def test_the_team_s_required_dependencies_are_installed_by_default():
    deps = " ".join(PROJECT["project"]["dependencies"])
    for name in ("pin", "qpsolvers", "osqp", "proxsuite", "daqp", "numpy", "scipy", "meshcat", "matplotlib"):
        assert name in deps, name


def test_reading_descriptions_and_result_files_does_not_import_pinocchio():
    import subprocess

    code = ("import sys, parallel_gpc.results, parallel_gpc.model as m; m.load_description('planar_4rrr'); "
            "print('pinocchio' in sys.modules, 'matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]
