"""Test-wide settings: each pytest session talks on its own DDS domain, so parallel runs never cross."""

from __future__ import annotations

import os
import random
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))  # shared test helpers: support.py
SHARED_DATA = (REPO_ROOT / ".." / "shared" / "data").resolve()

if "SSF_TEST_DOMAIN_FIXED" not in os.environ:
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(20, 200))
os.environ.setdefault("SSF_MIDDLEWARE", "dds")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The folder of real files written by other people's tools (beside the repository)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder not found next to the repository ({SHARED_DATA.name})")
    return SHARED_DATA
