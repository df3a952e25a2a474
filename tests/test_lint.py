"""The code has no undefined names, unused imports or other pyflakes errors (``ruff check``, rules in pyproject)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_finds_no_pyflakes_error():
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is None:
        pytest.fail("ruff is not installed — `make install` (or pip install -e '.[test]') installs it")
    done = subprocess.run([ruff, "check", "--no-cache", "components", "tasks", "flows", "benchmarks", "tests"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
