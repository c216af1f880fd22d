"""A process that works scan after scan keeps the memory it freed: the next scan's arrays reuse its pages.

glibc hands big blocks back to the kernel when they are freed (each array of a 64-beam scan is one), so every scan
faulted its arrays in afresh: 1 600 page faults a scan in the flow node, 2 700 in the fusion node, a few µs each
(docs/realtime.md). Holding the heap, as real-time ROS 2 executables do with `mallopt`, costs the node its peak
memory once instead."""

from __future__ import annotations

import ctypes
import ctypes.util
import os

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_TOP_PAD = -2
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_MAX = 32 << 20  # glibc refuses more on 64-bit: blocks above this still come from mmap
TOP_PAD = 64 << 20  # the heap grows in steps this big, so a scan rarely has to grow it
OPT_OUT = "SSF_KEEP_HEAP"  # "0" leaves glibc's defaults (to compare)


def hold_freed_memory() -> bool:
    """Ask glibc never to trim the heap and to serve blocks up to 32 MB from it; False where that is not glibc (or
    SSF_KEEP_HEAP=0), which changes nothing but speed."""
    if os.environ.get(OPT_OUT, "1") == "0":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    # the threshold first: setting it (or the trim threshold) turns off glibc's own adjustment of both
    return all(mallopt(param, value) == 1 for param, value in (
        (M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX), (M_TRIM_THRESHOLD, 2**31 - 1), (M_TOP_PAD, TOP_PAD)))
