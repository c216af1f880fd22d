"""Scan files: round trips through every format and encoding, files from other writers, broken files."""

import struct

import numpy as np
import pytest

from ssf_common import scans
from ssf_common.errors import DataError
from support import random_points

ALL_PCD_TYPES = np.dtype([
    ("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"), ("ring", "<u2"), ("offset", "i1"),
    ("id", "<i2"), ("count", "<i4"), ("flags", "<u4"), ("tick", "<i8"), ("stamp", "<u8"), ("time", "<f8"),
    ("normal", "<f4", (3,)), ("histogram", "<u2", (5,)),
])  # fmt: skip


@pytest.mark.parametrize("encoding", scans.PCD_ENCODINGS)
def test_pcd_round_trip_keeps_every_type_size_and_count(tmp_path, encoding):
    points = random_points(ALL_PCD_TYPES, 301)
    points["y"][[3, 7]] = np.nan
    path = tmp_path / f"cloud_{encoding}.pcd"
    scans.write_pcd(path, points, encoding=encoding)
    back = scans.read_points(path)
    assert back.dtype == ALL_PCD_TYPES
    assert back.tobytes() == points.tobytes()
    scan = scans.read_scan(path)
    assert scan.shape == (299, 4) and scan.dtype == np.float32
    np.testing.assert_array_equal(scan[:, 3], np.delete(points["intensity"], [3, 7]).astype(np.float32))


def test_pcd_written_organized_keeps_width_and_height(tmp_path):
    points = random_points(np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")]), 24).reshape(4, 6)
    scans.write_pcd(tmp_path / "organized.pcd", points)
    header = (tmp_path / "organized.pcd").read_bytes().split(b"DATA")[0]
    assert b"WIDTH 6\nHEIGHT 4\n" in header and b"POINTS 24\n" in header
    assert scans.read_points(tmp_path / "organized.pcd").tobytes() == points.tobytes()


def test_hand_written_pcd_with_padding_columns_and_comments(tmp_path):
    header = (
        "# written by hand\nVERSION .7\nFIELDS x y z _ intensity\nSIZE 4 4 4 1 4\nTYPE F F F U F\n"
        "COUNT 1 1 1 4 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA binary\n"
    )
    body = struct.pack("<fff4xf", 1.0, 2.0, 3.0, 0.5) + struct.pack("<fff4xf", -1.0, -2.0, -3.0, 0.25)
    (tmp_path / "padded.pcd").write_bytes(header.encode() + body)
    points = scans.read_points(tmp_path / "padded.pcd")
    assert points.dtype.names == ("x", "y", "z", "intensity")
    np.testing.assert_array_equal(scans.read_scan(tmp_path / "padded.pcd"), [[1, 2, 3, 0.5], [-1, -2, -3, 0.25]])
    ascii_text = header.replace("DATA binary", "DATA ascii").replace("SIZE 4 4 4 1 4", "SIZE 4 4 4 4 4")
    ascii_text = ascii_text.replace("COUNT 1 1 1 4 1", "COUNT 1 1 1 1 1")
    (tmp_path / "ascii.pcd").write_text(ascii_text + "1 2 3 0 0.5\n-1 -2 -3 0 0.25\n")
    np.testing.assert_array_equal(scans.read_scan(tmp_path / "ascii.pcd"), [[1, 2, 3, 0.5], [-1, -2, -3, 0.25]])


def test_lzf_decodes_overlapping_back_references():
    # literal 'ab', then a back reference of length 7 at distance 2: 'abababababa'... (liblzf format)
    stream = bytes([1]) + b"ab" + bytes([(5 << 5) | 0, 1])
    assert scans.lzf_decompress(stream, 9) == b"ababababa"
    long_run = bytes([0]) + b"z" + bytes([(7 << 5), 100, 0])
    assert scans.lzf_decompress(long_run, 110) == b"z" * 110


@pytest.mark.parametrize("kind", ["repetitive", "random", "mixed"])
def test_lzf_round_trip(kind):
    rng = np.random.default_rng(5)
    data = {
        "repetitive": b"lidar" * 3000 + bytes(5000),
        "random": rng.integers(0, 256, 20000, dtype=np.uint8).tobytes(),
        "mixed": np.repeat(rng.integers(0, 4, 4000, dtype=np.uint8), 3).tobytes() + rng.bytes(3000),
    }[kind]
    compressed = scans.lzf_compress(data)
    assert scans.lzf_decompress(compressed, len(data)) == data
    if kind == "repetitive":
        assert len(compressed) < len(data) // 20


@pytest.fixture(scope="module")
def open3d_files(tmp_path_factory):
    """x, y, z written by Open3D's own PCD and PLY writers (an independent implementation)."""
    o3d = pytest.importorskip("open3d")
    folder = tmp_path_factory.mktemp("open3d")
    xyz = np.random.default_rng(4).normal(scale=10, size=(500, 3)).astype(np.float32).astype(np.float64)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    files = {
        "compressed.pcd": {"write_ascii": False, "compressed": True},
        "binary.pcd": {"write_ascii": False},
        "binary.ply": {"write_ascii": False},
        "ascii.ply": {"write_ascii": True},
    }
    for name, options in files.items():
        assert o3d.io.write_point_cloud(str(folder / name), cloud, **options)
    return folder, xyz, o3d


@pytest.mark.parametrize("name", ["compressed.pcd", "binary.pcd", "binary.ply", "ascii.ply"])
def test_files_written_by_open3d_are_read(open3d_files, name):
    folder, xyz, _ = open3d_files
    scan = scans.read_scan(folder / name)
    tolerance = 1e-5 if name == "ascii.ply" else 0  # Open3D's ASCII PLY keeps 6 significant digits
    np.testing.assert_allclose(scan, xyz, rtol=tolerance, atol=tolerance)


def test_open3d_reads_our_compressed_pcd(open3d_files, tmp_path):
    _, xyz, o3d = open3d_files
    scans.write_pcd(tmp_path / "ours.pcd", xyz.astype(np.float32), encoding="binary_compressed")
    np.testing.assert_array_equal(np.asarray(o3d.io.read_point_cloud(str(tmp_path / "ours.pcd")).points), xyz)


def ply(fmt: str, vertices: bytes, before: str = "", after: str = "") -> bytes:
    header = (
        f"ply\nformat {fmt} 1.0\ncomment test\n{before}element vertex 2\nproperty float x\nproperty float y\n"
        f"property float z\nproperty uchar intensity\n{after}end_header\n"
    )
    return header.encode() + vertices


def test_ply_ascii_and_binary_with_other_elements(tmp_path):
    expected = [[1.5, 2, 3, 7], [-4, 5.25, -6, 200]]
    little, big = (b"".join(struct.pack(order + "fffB", *row) for row in expected) for order in "<>")
    faces = "element face 1\nproperty list uchar int vertex_indices\n"
    camera = "element camera 1\nproperty float a\nproperty float b\n"
    files = {
        "ascii.ply": ply("ascii", b"1.5 2 3 7\n-4 5.25 -6 200\n3 0 1 1\n", after=faces),
        "ascii_camera_first.ply": ply("ascii", b"9 9\n1.5 2 3 7\n-4 5.25 -6 200\n", before=camera),
        "little.ply": ply("binary_little_endian", little),
        "big.ply": ply("binary_big_endian", big),
        "little_camera_first.ply": ply("binary_little_endian", struct.pack("<ff", 9, 9) + little, before=camera),
    }
    for name, content in files.items():
        (tmp_path / name).write_bytes(content)
        np.testing.assert_array_equal(scans.read_scan(tmp_path / name), expected, err_msg=name)
    assert scans.read_points(tmp_path / "little.ply")["intensity"].dtype == np.uint8


def test_npy_and_kitti_bin(tmp_path):
    xyzi = np.random.default_rng(6).normal(size=(40, 4)).astype(np.float32)
    np.save(tmp_path / "xyz.npy", xyzi[:, :3].astype(np.float64))
    np.save(tmp_path / "xyzi.npy", xyzi)
    np.testing.assert_array_equal(scans.read_scan(tmp_path / "xyz.npy"), xyzi[:, :3])
    np.testing.assert_array_equal(scans.read_scan(tmp_path / "xyzi.npy"), xyzi)
    scans.write_bin(tmp_path / "000000.bin", xyzi)
    assert (tmp_path / "000000.bin").stat().st_size == 40 * 16
    np.testing.assert_array_equal(scans.read_scan(tmp_path / "000000.bin"), xyzi)
    scans.write_bin(tmp_path / "xyz.bin", xyzi[:, :3])
    np.testing.assert_array_equal(scans.read_scan(tmp_path / "xyz.bin")[:, 3], np.zeros(40))


def test_real_scans(shared_data):
    folder = shared_data / "lidar_scans"
    vlp16 = scans.read_points(folder / "vlp16_1673400472138016708.pcd")
    assert vlp16.size == 14831 and vlp16.dtype.itemsize == 32
    assert vlp16["channel"].max() <= 15 and np.all(np.isfinite(vlp16["distance"]))
    ranges = np.linalg.norm(np.stack([vlp16[axis] for axis in "xyz"], 1), axis=1)
    np.testing.assert_allclose(ranges, vlp16["distance"], atol=0.01)
    assert scans.read_scan(folder / "vlp16_1673400472138016708.pcd").shape == (14831, 4)
    assert scans.read_scan(folder / "vlp32_1713492677464078412.pcd").shape == (26216, 3)


def write_pcd_bytes(tmp_path, encoding="binary"):
    scans.write_pcd(tmp_path / "good.pcd", random_points(ALL_PCD_TYPES, 50), encoding=encoding)
    return (tmp_path / "good.pcd").read_bytes()


def replace_header(old: bytes, new: bytes):
    return lambda raw: raw.replace(old, new, 1)


BROKEN = {
    "binary_truncated": ("binary", lambda raw: raw[:-10], "truncated: .* bytes of binary point data"),
    "compressed_truncated": ("binary_compressed", lambda raw: raw[:-10], "truncated: .* bytes of compressed data"),
    "compressed_corrupt": ("binary_compressed", lambda raw: raw[:-400] + b"\xff" * 400, "corrupt compressed data"),
    "ascii_truncated": ("ascii", lambda raw: raw[: raw.rindex(b"\n", 0, -200)], "truncated: .* ASCII values"),
    "ascii_bad_number": ("ascii", replace_header(b"DATA ascii\n", b"DATA ascii\nnope "), "'x' holds a value"),
    "no_data_line": ("binary", lambda raw: raw.replace(b"DATA", b"DOTA", 1), "not a PCD file"),
    "unknown_encoding": ("binary", replace_header(b"DATA binary", b"DATA zipped"), "unknown DATA encoding 'zipped'"),
    "bad_type": ("binary", replace_header(b"TYPE F", b"TYPE Q"), "unsupported TYPE Q"),
    "count_mismatch": ("binary", replace_header(b"COUNT 1 ", b"COUNT "), "lists 14 FIELDS, 14 SIZE, 14 TYPE, 13 COUNT"),
    "points_mismatch": ("binary", replace_header(b"POINTS 50", b"POINTS 51"), "WIDTH 50 × HEIGHT 1 but POINTS 51"),
    "not_integer": ("binary", replace_header(b"WIDTH 50", b"WIDTH fifty"), "WIDTH value 'fifty' is not an integer"),
    "garbage": ("binary", lambda raw: bytes(range(256)) * 10, "not a PCD file"),
}


@pytest.mark.parametrize("case", BROKEN)
def test_broken_pcd_files_give_one_line(tmp_path, case):
    encoding, corrupt, problem = BROKEN[case]
    path = tmp_path / "broken.pcd"
    path.write_bytes(corrupt(write_pcd_bytes(tmp_path, encoding)))
    with pytest.raises(DataError, match=problem) as caught:
        scans.read_points(path)
    assert str(caught.value).startswith(str(path)) and "\n" not in str(caught.value)


PLY_ASCII_VERTEX = b"ply\nformat ascii 1.0\nelement vertex 1\n"


@pytest.mark.parametrize(
    "name, content, problem",
    [
        ("short.bin", bytes(30), "not a multiple of 16"),
        ("bad.npy", b"not numpy", "not a valid .npy"),
        ("wide.npy", None, "expected a numeric N×3 or N×4"),
        ("truncated.ply", ply("binary_little_endian", bytes(20)), "truncated"),
        ("short_ascii.ply", ply("ascii", b"1 2 3 4\n"), "truncated"),
        ("no_format.ply", b"ply\nelement vertex 1\nproperty float x\nend_header\n", "no format line"),
        ("lists.ply", PLY_ASCII_VERTEX + b"property list uchar float x\nend_header\n1 2\n", "list property"),
        ("weird.ply", PLY_ASCII_VERTEX + b"property quaternion q\nend_header\n", "not understood"),
        ("scan.xyz", b"1 2 3\n", "unsupported scan format '.xyz'"),
        ("nan.bin", np.full(8, np.nan, np.float32).tobytes(), "no point with finite x, y, z"),
        ("noz.npy", "structured", "no z field"),
    ],
)
def test_broken_scan_files_give_one_line(tmp_path, name, content, problem):
    path = tmp_path / name
    if name == "wide.npy":
        np.save(path, np.zeros((4, 7)))
    elif content == "structured":
        np.save(path, np.zeros(3, dtype=[("x", "f4"), ("y", "f4")]))
    else:
        path.write_bytes(content)
    with pytest.raises(DataError, match=problem) as caught:
        scans.read_scan(path)
    assert "\n" not in str(caught.value)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(DataError, match="missing.pcd: no such scan file"):
        scans.read_scan(tmp_path / "missing.pcd")


@pytest.mark.parametrize(
    ("real", "renamed", "fragment"),
    [
        ("scan.pcd", "scan.bin", "the content is a .pcd file, not .bin; rename it to scan.pcd"),
        ("scan.npy", "scan.bin", "the content is a .npy file, not .bin; rename it to scan.npy"),
        ("scan.ply", "scan.pcd", "the content is a .ply file, not .pcd; rename it to scan.ply"),
        ("scan.pcd", "scan.npy", "the content is a .pcd file, not .npy"),
    ],
)
def test_a_file_renamed_to_another_format_is_refused(tmp_path, real, renamed, fragment):
    xyz = np.random.default_rng(2).normal(size=(64, 3)).astype(np.float32)
    if real.endswith(".pcd"):
        scans.write_pcd(tmp_path / real, xyz, encoding="binary")
    elif real.endswith(".npy"):
        np.save(tmp_path / real, xyz)
    else:
        (tmp_path / real).write_bytes(ply("binary_little_endian", xyz.tobytes()))
    (tmp_path / real).rename(tmp_path / renamed)
    with pytest.raises(DataError) as caught:
        scans.read_scan(tmp_path / renamed)
    assert fragment in str(caught.value)


def test_text_named_bin_is_refused_rather_than_read_as_floats(tmp_path):
    path = tmp_path / "000000.bin"
    path.write_bytes(b"1.0 2.0 3.0 0.5\n" * 64)  # 1024 bytes: a whole number of 16-byte "points"
    with pytest.raises(DataError, match="the content is text, not KITTI .bin float32 points"):
        scans.read_scan(path)


def test_implausible_coordinates_are_dropped_and_counted(tmp_path):
    xyzi = np.array(
        [[1, 2, 3, 0.1], [1e30, 0, 0, 0.2], [np.nan, 0, 0, 0.3], [4, -999.5, 6, 0.4], [0, 0, -1000.5, 0.5]],
        dtype=np.float32,
    )
    scans.write_bin(tmp_path / "mixed.bin", xyzi)
    warnings: list[str] = []
    kept = scans.read_scan(tmp_path / "mixed.bin", warn=warnings.append)
    np.testing.assert_array_equal(kept, xyzi[[0, 3]])
    assert warnings == [f"{tmp_path / 'mixed.bin'}: dropped 3 of 5 points (1 with non-finite x/y/z, 2 beyond 1000 m)"]
    loaded = scans.load_scan(tmp_path / "mixed.bin", max_coordinate=1e31)
    assert (loaded.total, loaded.non_finite, loaded.too_far, len(loaded.points)) == (5, 1, 0, 4)
    assert scans.load_scan(tmp_path / "mixed.bin", max_coordinate=1000.5).too_far == 1
    with pytest.raises(DataError, match="max_coordinate must be a positive number"):
        scans.load_scan(tmp_path / "mixed.bin", max_coordinate=float("nan"))


def test_a_scan_of_far_points_only_is_an_error_not_a_scan(tmp_path):
    scans.write_pcd(tmp_path / "far.pcd", np.full((10, 3), 1e30, np.float32))
    with pytest.raises(DataError, match=r"far.pcd: no point with finite x, y, z within 1000 m \(10 points"):
        scans.read_scan(tmp_path / "far.pcd")
    np.save(tmp_path / "far64.npy", np.full((3, 3), 1e300))  # beyond float32 as well
    with pytest.raises(DataError, match="within 1000 m"):
        scans.read_scan(tmp_path / "far64.npy")


def test_fields_that_are_not_numbers_are_refused(tmp_path):
    np.save(tmp_path / "strings.npy", np.array([["1", "2", "3"]]))
    with pytest.raises(DataError, match="expected a numeric N×3 or N×4 array, got <U1"):
        scans.read_scan(tmp_path / "strings.npy")
    np.save(tmp_path / "named.npy", np.zeros(2, dtype=[("x", "U3"), ("y", "f4"), ("z", "f4")]))
    with pytest.raises(DataError, match="field 'x' holds <U3 values; expected numbers"):
        scans.read_scan(tmp_path / "named.npy")


def test_headers_that_promise_more_than_the_file_holds(tmp_path):
    huge_ascii = b"ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\nproperty float x\nend_header\n1\n"
    (tmp_path / "huge.ply").write_bytes(huge_ascii)
    with pytest.raises(DataError, match="truncated: 2 lines of ASCII data"):
        scans.read_points(tmp_path / "huge.ply")
    twice = PLY_ASCII_VERTEX + b"property float x\nproperty float x\nend_header\n1 2\n"
    (tmp_path / "twice.ply").write_bytes(twice)
    with pytest.raises(DataError, match="repeats a property name"):
        scans.read_points(tmp_path / "twice.ply")
    raw = write_pcd_bytes(tmp_path, "binary_compressed")
    head, body = raw.split(b"DATA binary_compressed\n")
    compressed = struct.unpack("<I", body[:4])[0]
    (tmp_path / "bomb.pcd").write_bytes(
        head.replace(b"POINTS 50", b"POINTS 5000000").replace(b"WIDTH 50", b"WIDTH 5000000")
        + b"DATA binary_compressed\n" + struct.pack("<II", compressed, 5000000 * ALL_PCD_TYPES.itemsize) + body[8:]
    )
    with pytest.raises(DataError, match="LZF cannot do that"):
        scans.read_points(tmp_path / "bomb.pcd")
