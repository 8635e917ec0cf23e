"""A regular and an editable install both import mmcsplat, and only under the mmcsplat namespace."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import attr
import attrs
import pluggy
import pytest

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "framework", "plugins", "backends", "datasets")
# Where each source folder's modules land in the wheel, from pyproject.toml's package-dir.
INSTALLED_AS = {folder: package.replace(".", "/")
                for package, folder in tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"].items()}

CHECK = """
import importlib, importlib.metadata, json, sys
modules = ["mmcsplat", "mmcsplat.cli", "mmcsplat.plugin_api", "mmcsplat.pipeline", "mmcsplat.plugins", "mmcsplat.backends",
           "mmcsplat.datasets", "mmcsplat.synthetic", "mmcsplat.plugins.registrations",
           "mmcsplat.backends.registrations", "mmcsplat.datasets.registrations"]
import mmcsplat.plugins.registrations, mmcsplat.backends.registrations, mmcsplat.datasets.registrations
# find_spec locates a module (importing its parents) without running it: enough to prove where it resolves.
files = {name: importlib.util.find_spec(name).origin for name in modules}
shadowing = [name for name in ("framework", "plugins", "backends", "datasets")
             if importlib.util.find_spec(name) is not None]
groups = sorted(ep.name for ep in importlib.metadata.entry_points(group="mmcsplat"))
print(json.dumps({"files": files, "shadowing": shadowing, "entry_points": groups}))
"""


def _build(tmp_path: Path, hook: str) -> tuple[Path, Path]:
    """Build a wheel with setuptools' PEP 517/660 ``hook`` from a copy of the sources; return (source, wheel)."""
    source = tmp_path / "src"
    source.mkdir()
    for name in SOURCES:
        path = REPO / name
        if path.is_dir():
            shutil.copytree(path, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(path, source / name)
    out = tmp_path / "wheel"
    out.mkdir()
    code = f"import setuptools.build_meta as b; print(b.{hook}({str(out)!r}))"
    result = subprocess.run([sys.executable, "-c", code], cwd=source, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    return source, out / result.stdout.strip().splitlines()[-1]


def _check_installed(site: Path, deps: Path) -> dict:
    """Import mmcsplat from ``site`` in an interpreter that sees no other site-packages."""
    code = f"import site, sys; sys.path[:0] = [{str(deps)!r}]; site.addsitedir({str(site)!r})\n" + CHECK
    # Run outside the repository: with -c the working directory is on sys.path.
    result = subprocess.run([sys.executable, "-S", "-c", code], cwd=site, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    import json

    return json.loads(result.stdout)


@pytest.fixture(scope="module")
def pure_deps(tmp_path_factory) -> Path:
    """The pure-Python packages mmcsplat needs to import, copied alone onto a private path."""
    deps = tmp_path_factory.mktemp("deps")
    for module in (pluggy, attr, attrs):
        package = Path(module.__file__).parent
        shutil.copytree(package, deps / package.name, ignore=shutil.ignore_patterns("__pycache__"))
    return deps


@pytest.mark.slow
@pytest.mark.parametrize("hook", ["build_wheel", "build_editable"])
def test_install_imports_under_mmcsplat_only(tmp_path, pure_deps, hook):
    source, wheel = _build(tmp_path, hook)
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        archive.extractall(site)
    if hook == "build_wheel":
        tops = {name.split("/")[0] for name in names if not name.split("/")[0].endswith(".dist-info")}
        assert tops == {"mmcsplat"}, tops
        # A subpackage left out of pyproject.toml's explicit package list installs without its modules.
        sources = {f"{INSTALLED_AS[top]}/{path.relative_to(REPO / top).as_posix()}"
                   for top in INSTALLED_AS for path in (REPO / top).rglob("*.py") if "__pycache__" not in path.parts}
        assert not sources - set(names), sorted(sources - set(names))
    report = _check_installed(site, pure_deps)
    assert report["shadowing"] == []
    assert report["entry_points"] == ["builtin-plugins", "builtin-readers", "builtin-renderers"]
    expected_root = site / "mmcsplat" if hook == "build_wheel" else source
    for module, file in report["files"].items():
        assert Path(file).is_relative_to(expected_root), (module, file)
    if hook == "build_editable":
        assert Path(report["files"]["mmcsplat.datasets"]).parent == source / "datasets"
        assert Path(report["files"]["mmcsplat"]).parent == source / "framework"
