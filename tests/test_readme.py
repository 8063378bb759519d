"""README.md as a test: every ```python block runs as printed, and CI runs the
README's test command.

Each block runs in a fresh interpreter, as a reader pasting it would run it:
the library's defaults (float32, no x64, none of conftest's strictness), the
working directory a temporary folder, and warnings as errors (a warning in the
README's own walk is a defect a reader would see).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
TIMEOUT_S = 600  # the longest block takes about a minute on 2 cores; this only stops a hang


def _blocks(language: str) -> list[tuple[int, str]]:
    """(line number, code) of every fenced block in ``language``."""
    out = []
    for m in re.finditer(rf"^```{language}[ \t]*\n(.*?)^```[ \t]*$", README, re.M | re.S):
        out.append((README.count("\n", 0, m.start()) + 1, m.group(1)))
    return out


PYTHON_BLOCKS = _blocks("python")


def _param(line: int, code: str):
    marks = [pytest.mark.slow] if "stage.simulate" in code else []
    return pytest.param(code, id=f"README.md:{line}", marks=marks)


def test_the_readme_has_python_blocks():
    assert len(PYTHON_BLOCKS) >= 2  # the jit example and the main walk; a fence typo would silently test nothing


@pytest.mark.parametrize("code", [_param(line, code) for line, code in PYTHON_BLOCKS])
def test_python_block_runs_as_printed(code, tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    done = subprocess.run(
        [sys.executable, "-W", "error", "-c", code],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    if done.returncode != 0:
        pytest.fail(f"exit {done.returncode}\n--- stderr (tail) ---\n{done.stderr[-4000:]}", pytrace=False)


def test_ci_runs_the_readme_test_command():
    """.ci/run runs the README's test command (its `&&` parts as lines, in order), with `ruff check .` before
    the tests."""
    quick = README.split("## Quick start", 1)[1]
    bash = [code for _, code in _blocks("bash") if code in quick][0]
    lines = [line.strip() for line in bash.strip().splitlines()]
    assert len(lines) == 2, "the quick start is exactly two commands"
    test_command = next(line for line in lines if "pytest" in line)
    parts = [p.strip() for p in test_command.split("&&")]
    ci = [line.strip() for line in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    ci = [line for line in ci if line and not line.startswith("#")]
    where = [ci.index(p) if p in ci else -1 for p in parts]
    assert -1 not in where and where == sorted(where), f".ci/run must run {parts} in order; it runs {ci}"
    assert "ruff check ." in ci and ci.index("ruff check .") < where[-1], ".ci/run lints before the tests"
