"""A folder of stored perception: each scan's flow and static mask, written on the first run of a drive and read back
on the next, so that an odometry change is measured over a whole route in minutes instead of an hour (perception
takes ~90 % of a drive's time). Keyed by the drive and the perception settings, not by the code: after changing the
flow or the segmentation, start a new folder."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from ssf_common.errors import ConfigError, DataError
from ssf_eval.odom.evaluate import Perceived, OdomPerception
from ssf_eval.odom.sequence import SimScan

KEY_FILE = "drive.json"


class CachedPerception:
    """OdomPerception that stores what it computes for each scan in `folder` and reads it back where stored."""

    def __init__(self, perception: OdomPerception, folder: Path, drive: dict) -> None:
        self.perception = perception
        self.folder = Path(folder)
        self.drive = {**drive, "masks": perception.masks.value, "maskless_flow": perception.plain is not None}
        self.read = 0
        self.computed = 0
        self.missed_after_read = False

    def reset(self) -> None:
        """A new drive: check that the folder was written for this drive, or claim an empty one."""
        self.perception.reset()
        self.read = self.computed = 0
        self.missed_after_read = False
        self.folder.mkdir(parents=True, exist_ok=True)
        key = self.folder / KEY_FILE
        if key.is_file():
            try:
                stored = json.loads(key.read_text())
            except (OSError, ValueError) as error:
                raise DataError(f"perception cache {self.folder}: unreadable {KEY_FILE} ({error})") from None
            changed = sorted(name for name in (set(stored) | set(self.drive)) - {"maskless_flow"}
                             if stored.get(name) != self.drive.get(name))
            if changed:
                raise ConfigError(f"perception cache {self.folder} was written for another drive (differs in "
                                  f"{', '.join(changed)}): name a new folder")
            if self.drive["maskless_flow"] and not stored.get("maskless_flow"):
                raise ConfigError(f"perception cache {self.folder} holds no maskless flow (written without the "
                                  "'flow' method): name a new folder to compare it")
        elif any(self.folder.iterdir()):
            raise ConfigError(f"perception cache {self.folder} is not empty and holds no {KEY_FILE}: name a new folder")
        else:
            key.write_text(json.dumps(self.drive, indent=1, sort_keys=True))

    def __call__(self, scan: SimScan) -> Perceived:
        """The stored perception of this scan, or the computed one (then stored)."""
        path = self.folder / f"scan_{scan.index:06d}.npz"
        if path.is_file():
            stored = self.load(path, len(scan.points))
            if stored is not None:
                self.read += 1
                return stored
        if self.read and not self.missed_after_read:
            self.missed_after_read = True  # the segmentation carried from the last scan was not computed here
            print(f"perception cache {self.folder}: ends before scan {scan.index}; from here perception starts afresh, "
                  "so these scans differ from an uncached drive", file=sys.stderr)
        perceived = self.perception(scan)
        self.computed += 1
        arrays = {"flow": perceived.flow, "dynamic_prob": perceived.dynamic_prob, "ms": np.float64(perceived.ms)}
        if perceived.flow_plain is not None:
            arrays["flow_plain"] = perceived.flow_plain
        if perceived.ego is not None:
            arrays["ego"] = perceived.ego
        partial = path.with_suffix(".part.npz")
        np.savez(partial, **arrays)
        partial.replace(path)  # whole files only: a killed drive leaves no half-written scan
        return perceived

    def load(self, path: Path, points: int) -> Perceived | None:
        """One stored scan, None (with a line naming it) where it is unreadable or does not fit the scan."""
        try:
            with np.load(path) as stored:
                flow, dynamic = stored["flow"], stored["dynamic_prob"]
                plain = stored["flow_plain"] if "flow_plain" in stored else None
                ego = stored["ego"] if "ego" in stored else None  # folders written before the ego was kept: refitted
                ms = float(stored["ms"])
        except (OSError, ValueError, KeyError) as error:
            print(f"perception cache {path}: unreadable ({error}); computing it again", file=sys.stderr)
            return None
        if self.perception.plain is None:
            plain = None  # stored for the 'flow' method, not asked for this time
        if flow.shape != (points, 3) or dynamic.shape != (points,) or (plain is None) != (self.perception.plain is None):
            print(f"perception cache {path}: does not fit this scan of {points} points; computing it again",
                  file=sys.stderr)
            return None
        return Perceived(plain, flow, dynamic, ms, ego)
