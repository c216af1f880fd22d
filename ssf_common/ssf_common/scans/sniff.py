"""What a file's first bytes say it is, whatever its name says."""

from __future__ import annotations

import re

_MAGICS = (
    (b"\x93NUMPY", ".npy"),
    (b"\x89MCAP", "an MCAP bag"),
    (b"SQLite format 3\x00", "an sqlite3 database"),
    (b"PK\x03\x04", "a zip archive (.npz?)"),
    (b"\x1f\x8b", "a gzip file"),
    (b"\x89PNG", "a PNG image"),
)
_PLY = re.compile(rb"ply\r?\n")
_PCD = re.compile(rb"\s*(#[^\n]*\n\s*)*(VERSION|FIELDS)\s")
_TEXT_BYTES = frozenset(b"\t\n\r" + bytes(range(0x20, 0x7F)))


def sniff(raw: bytes) -> str | None:
    """'.npy', '.pcd', '.ply', a description of another known format, 'text', or None when unknown."""
    for magic, kind in _MAGICS:
        if raw.startswith(magic):
            return kind
    if _PLY.match(raw):
        return ".ply"
    head = raw[:1024]
    if _PCD.match(head):
        return ".pcd"
    sample = raw[:512]
    if sample and all(byte in _TEXT_BYTES for byte in sample):
        return "text"
    return None
