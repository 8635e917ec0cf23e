"""The architecture of docs/architecture.md holds: no import cycle, the rooms layered, plugins on the public
API only, no private core name used outside the core, and the style ruff keeps."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import grimp
import pytest

REPO = Path(__file__).resolve().parents[1]
#: The folders installed as mmcsplat's subpackages beside the core (pyproject.toml's package-dir).
PLUGIN_FOLDERS = ("plugins", "backends", "datasets")


@pytest.fixture(scope="module")
def package_tree(tmp_path_factory) -> Path:
    """The installed layout of ``mmcsplat`` as links, so that grimp sees the plugin folders inside it."""
    root = tmp_path_factory.mktemp("layout")
    package = root / "mmcsplat"
    package.mkdir()
    for entry in (REPO / "framework").iterdir():
        if entry.name != "__pycache__":
            (package / entry.name).symlink_to(entry)
    for folder in PLUGIN_FOLDERS:
        (package / folder).symlink_to(REPO / folder)
    return root


def _graph(package_tree: Path) -> grimp.ImportGraph:
    sys.path.insert(0, str(package_tree))
    saved = {name: module for name, module in sys.modules.items() if name == "mmcsplat" or name.startswith("mmcsplat.")}
    try:
        for name in saved:
            del sys.modules[name]
        return grimp.build_graph("mmcsplat", include_external_packages=False, cache_dir=None)
    finally:
        sys.path.remove(str(package_tree))
        sys.modules.update(saved)


def _cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), type-checking imports included."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for imported in graph.find_modules_directly_imported_by(module):
            if imported not in index:
                visit(imported)
                low[module] = min(low[module], low[imported])
            elif imported in on_stack:
                low[module] = min(low[module], index[imported])
        if low[module] == index[module]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == module:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for module in sorted(graph.modules):
        if module not in index:
            visit(module)
    return found


def test_the_module_graph_has_no_cycle(package_tree):
    graph = _graph(package_tree)
    assert "mmcsplat.plugins.registrations" in graph.modules  # the plugin folders are part of the graph
    assert _cycles(graph) == []


def test_layering_contracts_hold(package_tree):
    """pyproject.toml's import-linter contracts: rooms layered, plugins on the public API, no plugin
    imported by the core, a leaf hookspec module."""
    lint = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert lint, "import-linter is a test dependency"
    result = subprocess.run([lint, "--config", str(REPO / "pyproject.toml"), "--no-cache"], cwd=package_tree,
                            env={"PYTHONPATH": str(package_tree), "PATH": str(Path(sys.executable).parent)},
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def _private_core_imports(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "mmcsplat":
            parts = node.module.split(".")
            in_core = len(parts) < 2 or parts[1] not in PLUGIN_FOLDERS
            private = [alias.name for alias in node.names if alias.name.startswith("_") and alias.name != "__version__"]
            if in_core and (private or any(part.startswith("_") for part in parts)):
                found.append(f"{path.relative_to(REPO)}:{node.lineno}: from {node.module} import {', '.join(private)}")
    return found


def test_nothing_outside_the_core_imports_a_private_core_name():
    outside = [path for folder in (*PLUGIN_FOLDERS, "tests") for path in sorted((REPO / folder).rglob("*.py"))]
    assert [line for path in outside for line in _private_core_imports(path)] == []


def test_ruff_finds_nothing():
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(REPO)], cwd=REPO, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-4000:]
