"""A run directory's file names (mmcsplat.storage.run) and the synthetic capture's ground truth
(mmcsplat.storage.ground_truth) are each spelt once in the sources: every other module imports the name."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from mmcsplat.storage import ground_truth, run

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("framework", "plugins", "backends", "datasets")
HOMES = {
    **{value: Path("framework/storage/run.py") for name, value in vars(run).items() if name.isupper() and isinstance(value, str)},
    ground_truth.GROUND_TRUTH: Path("framework/storage/ground_truth.py"),
}


def docstrings(tree: ast.AST) -> set[int]:
    """The ids of the docstring nodes of ``tree``: prose may name a file."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                found.add(id(first.value))
    return found


def spellings(path: Path, names: set[str]) -> list[tuple[str, int]]:
    """(name, line) of each string literal in ``path`` that is one of ``names``, or a path ending in one
    (a sentence, with spaces, may name a file: a help text, a message)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skipped = docstrings(tree)
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skipped:
            hits += [(name, node.lineno) for name in names if node.value == name or (node.value.endswith(f"/{name}") and " " not in node.value)]
    return hits


def test_the_names_are_found_where_they_are_defined():
    # The check below would pass vacuously if it could not see a literal: it sees the definitions.
    for name, home in HOMES.items():
        assert spellings(ROOT / home, {name}), f"{home} does not spell {name!r}"


@pytest.mark.parametrize("folder", SOURCES)
def test_each_run_file_name_is_spelt_once(folder):
    strays = [
        f"{path.relative_to(ROOT)}:{line}: {name!r} (import it from {HOMES[name]})"
        for path in sorted((ROOT / folder).rglob("*.py"))
        for name, line in spellings(path, set(HOMES))
        if path.relative_to(ROOT) != HOMES[name]
    ]
    assert not strays, "\n".join(strays)
