"""rosbag2 bags: read any MCAP or sqlite3 bag, write MCAP bags, and the `ssf bag` / `ssf record` tools.

Names are imported lazily so that registering the commands stays cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "open_bag": "reader",
    "BagReader": "reader",
    "BagWriter": "writer",
    "BagWriterConfig": "writer",
    "BagInfo": "types",
    "BagMessage": "types",
    "FileInfo": "types",
    "TopicInfo": "types",
    "Qos": "qos",
    "default_profile": "qos",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'ssf_common.bags' has no attribute '{name}'")
    return getattr(importlib.import_module(f"ssf_common.bags.{_EXPORTS[name]}"), name)
