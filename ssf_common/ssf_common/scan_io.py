"""Moved to `ssf_common.scans` (one module per format); this name stays until every caller has moved."""

from ssf_common.scans import (
    PCD_ENCODINGS,
    XYZ,
    lzf_compress,
    lzf_decompress,
    read_points,
    read_scan,
    write_bin,
    write_pcd,
)

__all__ = ["PCD_ENCODINGS", "XYZ", "lzf_compress", "lzf_decompress", "read_points", "read_scan", "write_bin", "write_pcd"]
