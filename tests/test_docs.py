"""The documentation says what the code does."""

from __future__ import annotations

from pathlib import Path

from mmcsplat.cli.main import COMMANDS, reference_markdown

REPO = Path(__file__).resolve().parents[1]


def test_cli_reference_is_generated_from_the_commands():
    page = (REPO / "docs" / "cli.md").read_text(encoding="utf-8")
    assert page == reference_markdown(), "docs/cli.md is stale: regenerate it (see mmcsplat.cli.main.reference_markdown)"


def test_readme_lists_every_command():
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    missing = [name for name in COMMANDS if f"`mmcsplat {name}" not in readme]
    assert not missing, f"README.md's command table lacks {missing}"
