"""The build backend of `pip install .` (PEP 517; pyproject.toml names it): builds the
Python module cvt_engine with the project's CMake, for the Python that runs pip, and packs
it with the shipped configurations into a wheel. It needs nothing from a package index:
CMake, a C++20 compiler and the engine's Debian packages (docs/install.md) do the work.

The build folder is build/pip-cpXY in the source tree (CVT_PIP_BUILD_DIR overrides it), so
that a second install rebuilds only what changed. pip shows CMake's output with -v.
CVT_PIP_PACKAGE_DIR=build/python/cvt_engine packs a package `make build` has built already
(for the same Python) instead of building it again.
"""
import base64
import hashlib
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
NAME = "cvt_engine"


def _version():
    with open(os.path.join(ROOT, "CMakeLists.txt")) as f:
        return re.search(r"project\(cvt_engine VERSION ([0-9.]+)", f.read()).group(1)


def _tag():
    py = f"cp{sys.version_info.major}{sys.version_info.minor}"
    return f"{py}-{py}-" + sysconfig.get_platform().replace("-", "_").replace(".", "_")


def _metadata():
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        readme = f.read()
    return (f"Metadata-Version: 2.1\nName: cvt-engine\nVersion: {_version()}\n"
            "Summary: Dynamics of a chain CVT: an 84-link rocker-pin chain with Hertz contacts and friction\n"
            "License: BSD-3-Clause\nRequires-Python: >=3.11\nRequires-Dist: numpy\n"
            "Provides-Extra: pandas\nRequires-Dist: pandas; extra == \"pandas\"\n"
            "Provides-Extra: xarray\nRequires-Dist: xarray; extra == \"xarray\"\n"
            "Description-Content-Type: text/markdown\n\n" + readme)


def _dist_info():
    return f"{NAME}-{_version()}.dist-info"


def get_requires_for_build_wheel(config_settings=None):
    return []


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    d = os.path.join(metadata_directory, _dist_info())
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "METADATA"), "w", encoding="utf-8") as f:
        f.write(_metadata())
    return _dist_info()


def _build():
    """The package folder built by CMake for this Python."""
    build = os.environ.get("CVT_PIP_BUILD_DIR") or os.path.join(
        ROOT, "build", f"pip-cp{sys.version_info.major}{sys.version_info.minor}")
    configure = ["cmake", "-S", ROOT, "-B", build, "-DCMAKE_BUILD_TYPE=Release", f"-DPython_EXECUTABLE={sys.executable}",
                 "-DCVT_BUILD_TESTS=OFF", "-DCVT_BUILD_BENCHMARKS=OFF", "-DCVT_BUILD_VIEWER=OFF",
                 "-DCVT_BUILD_PYTHON=ON", "-DCVT_REQUIRE_ALL=OFF"]
    for cmd in (configure, ["cmake", "--build", build, "--target", "cvt_engine_core", "-j", str(os.cpu_count() or 1)]):
        print("cvt-engine:", " ".join(cmd), flush=True)
        if subprocess.run(cmd).returncode != 0:
            raise RuntimeError(f"cvt-engine: `{' '.join(cmd)}` failed: see its output above (pip install -v); "
                               "the packages it needs: docs/install.md")
    package = os.path.join(build, "python", NAME)
    if not any(n.startswith("_core") and n.endswith(".so") for n in os.listdir(package)):
        raise RuntimeError(f"cvt-engine: the build made no extension in {package}: is pybind11-dev installed?")
    return package


def _record_line(arc, data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{arc},sha256={digest},{len(data)}"


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    package = os.environ.get("CVT_PIP_PACKAGE_DIR") or _build()
    files = {}
    for name in sorted(os.listdir(package)):
        if name.endswith((".py", ".pyi", ".so")) or name == "py.typed":  # configs/: from the source, below
            with open(os.path.join(package, name), "rb") as f:
                files[f"{NAME}/{name}"] = f.read()
    configs = os.path.join(ROOT, "configs")
    for name in sorted(os.listdir(configs)):
        if name.endswith(".toml"):
            with open(os.path.join(configs, name), "rb") as f:
                files[f"{NAME}/configs/{name}"] = f.read()
    info = _dist_info()
    with open(os.path.join(ROOT, "LICENSE"), "rb") as f:
        files[f"{info}/LICENSE"] = f.read()
    files[f"{info}/METADATA"] = _metadata().encode()
    files[f"{info}/WHEEL"] = (f"Wheel-Version: 1.0\nGenerator: cvt_build\nRoot-Is-Purelib: false\n"
                              f"Tag: {_tag()}\n").encode()
    record = [_record_line(arc, data) for arc, data in files.items()] + [f"{info}/RECORD,,"]
    wheel = f"{NAME}-{_version()}-{_tag()}.whl"
    os.makedirs(wheel_directory, exist_ok=True)
    with zipfile.ZipFile(os.path.join(wheel_directory, wheel), "w", zipfile.ZIP_DEFLATED) as z:
        for arc, data in files.items():
            z.writestr(arc, data)
        z.writestr(f"{info}/RECORD", "\n".join(record) + "\n")
    return wheel
