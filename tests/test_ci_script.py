"""CI installs and tests exactly as README.md tells a user to."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_commands():
    blocks = re.findall(r"```bash\n(.*?)```", (REPO / "README.md").read_text(), flags=re.S)
    setup, _main_job, tests = (block.strip() for block in blocks[:3])
    ci_lines = (REPO / ".ci" / "run").read_text().splitlines()
    assert setup in ci_lines
    assert tests in ci_lines
