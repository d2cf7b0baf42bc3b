"""Packaging: every package is listed, the public API is declared, and a built wheel imports."""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

import univtac_data

ROOT = Path(__file__).resolve().parents[1]
MAPPING = {"univtac_data": "univtac_data", "univtac_data.generators": "generators",
           "univtac_data.loaders": "loaders", "univtac_data.validators": "validators"}


def _packages_on_disk() -> set[str]:
    found = set()
    for package, folder in MAPPING.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            name = ".".join([package, *rel.parts]) if rel.parts else package
            if not any(name.startswith(other + ".") or name == other for other in MAPPING if other != package
                       and other.startswith(package + ".")):
                found.add(name)
    return found


def test_every_package_is_listed_in_pyproject():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert set(config["packages"]) == _packages_on_disk()
    assert config["package-dir"] == MAPPING


def test_public_api_is_declared():
    for name in univtac_data.__all__:
        assert hasattr(univtac_data, name), name
    assert univtac_data.FORMAT_VERSION == "2.0"


@pytest.mark.slow
def test_built_wheel_imports_every_package(tmp_path):
    build = subprocess.run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir",
                            str(tmp_path / "dist"), str(ROOT)], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stdout[-2000:] + build.stderr[-2000:]
    wheel = next((tmp_path / "dist").glob("univtac_data-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    for package in _packages_on_disk():
        assert package.replace(".", "/") + "/__init__.py" in names, package
    # A fresh environment that sees the dependencies but not the editable install: unpack the wheel into it.
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    site = Path(subprocess.check_output(
        [str(venv / "bin/python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        text=True).strip())
    zipfile.ZipFile(wheel).extractall(site)
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    code = ("import univtac_data, univtac_data.generators, univtac_data.loaders, univtac_data.validators, "
            "univtac_data.cli.main; print(univtac_data.__file__)")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([str(venv / "bin/python"), "-c", code], capture_output=True, text=True, cwd=tmp_path,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().startswith(str(site)), out.stdout
