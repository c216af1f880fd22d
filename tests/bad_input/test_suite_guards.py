"""The suite guards itself: in CI, tests that need the shared data fail when it is missing instead of skipping."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
NEEDS_DATA = "tests/ssf_common/test_scans.py::test_real_scans"


def run_pytest_without_data(tmp_path: Path, ci: str | None) -> subprocess.CompletedProcess:
    env = {**os.environ, "SSF_SHARED_DATA": str(tmp_path / "no_data_here")}
    env.pop("CI", None)
    if ci is not None:
        env["CI"] = ci
    return subprocess.run(
        [sys.executable, "-P", "-m", "pytest", "-q", "-p", "no:cacheprovider", NEEDS_DATA],
        cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_missing_shared_data_fails_in_ci_and_skips_elsewhere(tmp_path):
    in_ci = run_pytest_without_data(tmp_path, "true")
    assert in_ci.returncode == 1, in_ci.stdout
    assert "CI must provide it" in in_ci.stdout and "1 error" in in_ci.stdout
    local = run_pytest_without_data(tmp_path, None)
    assert local.returncode == 0, local.stdout
    assert "1 skipped" in local.stdout
