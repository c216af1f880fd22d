"""Test-wide settings: each pytest session talks on its own DDS domain, so parallel runs never cross."""

from __future__ import annotations

import importlib
import os
import random
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
# The test folders share the packages' names (tests/ssf_common, ...). Import the packages before the tests
# folder joins sys.path, or `ssf_common` would resolve to the test folder as a namespace package and
# importlib.resources would look for package data there.
for folder in sorted(TESTS.iterdir()):
    if folder.is_dir() and folder.name.isidentifier():
        try:
            importlib.import_module(folder.name)
        except ModuleNotFoundError:
            pass
sys.path.insert(0, str(TESTS))  # shared test helpers: support.py
SHARED_DATA = Path(os.environ.get("SSF_SHARED_DATA") or REPO_ROOT / ".." / "shared" / "data").resolve()

if "SSF_TEST_DOMAIN_FIXED" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(20, 200))
os.environ.setdefault("SSF_MIDDLEWARE", "dds")


def running_in_ci() -> bool:
    """Whether CI runs the suite (CI=true, as GitHub Actions, GitLab and most others set it)."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The folder of real files written by other people's tools (beside the repository).

    Missing on a developer's machine: the tests that need it skip. Missing in CI: they fail, so that a
    broken checkout of the data never passes as green."""
    if not SHARED_DATA.is_dir():
        message = f"shared data folder not found next to the repository ({SHARED_DATA})"
        if running_in_ci():
            pytest.fail(f"{message}; CI must provide it", pytrace=False)
        pytest.skip(message)
    return SHARED_DATA
