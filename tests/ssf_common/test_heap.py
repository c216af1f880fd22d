"""Holding the heap: a process that frees a scan's arrays reuses their pages for the next scan."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

FAULTS_PER_SCAN = """
import resource, sys
import numpy as np
from ssf_common.heap import hold_freed_memory
held = hold_freed_memory()
def scan():  # four 8 MB arrays written, then freed together
    arrays = [np.ones(8 << 20, np.uint8) for _ in range(4)]
scan()  # the first scan faults its pages in either way
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    scan()
print(held, (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 20)
"""


def faults_per_scan(keep: str) -> tuple[bool, float]:
    out = subprocess.run([sys.executable, "-c", FAULTS_PER_SCAN], env={**os.environ, "SSF_KEEP_HEAP": keep},
                         capture_output=True, text=True, check=True).stdout.split()
    return out[0] == "True", float(out[1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_arrays_are_reused_without_page_faults() -> None:
    held, faults = faults_per_scan("1")
    assert held
    assert faults < 100  # 32 MB is 8192 pages: none faulted in again
    released, faults_default = faults_per_scan("0")
    assert not released
    assert faults_default > 1000  # glibc's default: the freed top of the heap goes back to the kernel
