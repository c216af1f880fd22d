"""Valid samples of every file the project reads; the bad-input suite breaks them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ssf_common import messages, scans
from ssf_common.bags.qos import default_profile
from ssf_common.bags.writer import BagWriter

T0 = 1_650_000_000_000_000_000


def ply_sample(xyz: np.ndarray) -> bytes:
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % len(xyz)
    header += b"property float x\nproperty float y\nproperty float z\nend_header\n"
    return header + xyz.astype("<f4").tobytes()


@pytest.fixture(scope="session")
def scan_samples(tmp_path_factory) -> dict[str, bytes]:
    """One valid small scan per format the scans package reads, by suffix."""
    folder = tmp_path_factory.mktemp("scan_samples")
    xyzi = np.random.default_rng(0).normal(scale=20.0, size=(24, 4)).astype(np.float32)
    np.save(folder / "s.npy", xyzi)
    scans.write_bin(folder / "s.bin", xyzi)
    scans.write_pcd(folder / "s.pcd", xyzi, encoding="ascii")
    (folder / "s.ply").write_bytes(ply_sample(xyzi[:, :3]))
    return {suffix: (folder / f"s{suffix}").read_bytes() for suffix in (".npy", ".bin", ".pcd", ".ply")}


@pytest.fixture(scope="session")
def bag_samples(tmp_path_factory) -> dict[str, bytes]:
    """A small valid bag: its MCAP storage file, its metadata.yaml, and a sqlite3 file of the same messages."""
    folder = tmp_path_factory.mktemp("bag_sample") / "bag"
    string = messages.msg_type("std_msgs/msg/String")
    with BagWriter(folder) as writer:
        writer.add_topic("/chatter", "std_msgs/msg/String", [default_profile()])
        for i in range(12):
            writer.write("/chatter", messages.serialize(string(data=f"hello {i}")), T0 + i * 50_000_000)
    (mcap,) = folder.glob("*.mcap")
    return {
        ".mcap": mcap.read_bytes(),
        "metadata.yaml": (folder / "metadata.yaml").read_bytes(),
        ".db3": _sqlite_sample(tmp_path_factory.mktemp("db3") / "s.db3"),
    }


def _sqlite_sample(path: Path) -> bytes:
    import sqlite3

    db = sqlite3.connect(path)
    db.executescript(
        """
        CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
            serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
        CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL,
            data BLOB NOT NULL);
        INSERT INTO topics VALUES (1, '/chatter', 'std_msgs/msg/String', 'cdr', '');
        """
    )
    string = messages.msg_type("std_msgs/msg/String")
    db.executemany(
        "INSERT INTO messages VALUES (?, 1, ?, ?)",
        [(i + 1, T0 + i * 50_000_000, messages.serialize(string(data=f"hi {i}"))) for i in range(8)],
    )
    db.commit()
    db.close()
    return path.read_bytes()
