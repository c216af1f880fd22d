"""Every reader against generated hostile input: it returns what it promises, or raises one SsfError line.

Nothing else may escape (no UnicodeDecodeError, RecursionError, ValueError...). The readers are found in
their registries where one exists (scan formats, bag storages), so a format added there is covered here.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from bad_input.hostile import SUITE, finite_within, mutations, one_line, refused_or, yaml_documents
from ssf_bringup.launcher import load_graph
from ssf_common import config, messages, pointcloud, scans
from ssf_common.arrays import read_array
from ssf_common.bags import reader as bag_reader
from ssf_common.bags.qos import parse_profiles
from ssf_common.errors import SsfError
from ssf_common.middleware.params import parse_ros_args, read_params_file

SCENARIO = (Path(__file__).resolve().parents[2] / "sim_bridge" / "sim_bridge" / "scenarios" / "sparse_50.yaml").read_text()
GRAPH = resources.files("ssf_bringup").joinpath("graphs/demo.yaml").read_text()
PARAMS = "/**:\n  ros__parameters:\n    rate: 5.0\nmy_node:\n  ros__parameters:\n    lidar: {rows: 32, frame: lidar}\n"
FLOW_CONFIG = "preprocess:\n  points: 4096\n  max_range: 35.0\nrigid:\n  cluster_voxel: 0.5\n"


def load_scenario(path: Path):
    from sim_bridge.scenario import load_scenario as load

    return load(path)


def load_flow_config(path: Path):
    from ssf_flow_node.core.estimator import FlowConfig

    return config.build(FlowConfig, config.read_yaml(path), source=str(path))


YAML_READERS = {
    "scenario": (load_scenario, SCENARIO),
    "graph": (load_graph, GRAPH),
    "params file": (lambda path: read_params_file(path, "my_node"), PARAMS),
    "flow config": (load_flow_config, FLOW_CONFIG),
    "any config": (config.read_yaml, SCENARIO),
}


@pytest.mark.parametrize("reader", sorted(YAML_READERS))
def test_yaml_readers_answer_hostile_files_in_one_line(tmp_path, reader):
    read, sample = YAML_READERS[reader]
    path = tmp_path / "hostile.yaml"

    @SUITE
    @given(content=yaml_documents(sample))
    def check(content: bytes) -> None:
        path.write_bytes(content)
        try:
            read(path)
        except SsfError as err:
            assert str(path) in one_line(err)  # the line names the file

    check()


@SUITE
@given(value=st.text(max_size=200), name=st.text(max_size=12))
def test_override_items_are_parsed_or_refused_in_one_line(value, name):
    for item in (f"agents.count:={value}", f"{name}={value}", value):
        parsed = refused_or(lambda: config.parse_overrides([item], "-p"))
        if parsed is not None:
            assert len(parsed) == 1
    refused_or(lambda: parse_ros_args(["--ros-args", "-p", f"x:={value}", "-r", value], "node"))


@pytest.mark.parametrize("suffix", scans.SUFFIXES)
def test_every_scan_format_answers_broken_files_in_one_line(tmp_path, scan_samples, suffix):
    assert suffix in scan_samples, f"add a valid {suffix} sample to tests/bad_input/conftest.py"
    path = tmp_path / f"scan{suffix}"

    @SUITE
    @given(content=mutations(scan_samples[suffix]))
    def check(content: bytes) -> None:
        path.write_bytes(content)
        points = refused_or(lambda: scans.read_scan(path, warn=None))
        if points is not None:
            assert points.dtype == np.float32 and points.ndim == 2 and points.shape[1] in (3, 4)
            assert len(points) > 0 and finite_within(points, scans.MAX_COORDINATE_M)

    check()


def test_every_scan_format_has_a_sample(scan_samples):
    assert set(scans.SUFFIXES) <= set(scan_samples)


extreme_floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.sampled_from([1e30, -1e30, 1e3, -1e3, 1000.0001, float(np.finfo(np.float32).max)]),
)


@SUITE
@given(
    xyz=hnp.arrays(np.float32, st.tuples(st.integers(1, 40), st.just(3)), elements=extreme_floats),
    bound=st.sampled_from([scans.MAX_COORDINATE_M, 1.0, 1e6]),
    suffix=st.sampled_from([".npy", ".bin", ".pcd"]),
)
def test_extreme_coordinates_are_dropped_and_counted(tmp_path_factory, xyz, bound, suffix):
    path = tmp_path_factory.getbasetemp() / f"extreme{suffix}"
    {".npy": np.save, ".bin": scans.write_bin, ".pcd": scans.write_pcd}[suffix](path, xyz)
    finite = np.isfinite(xyz).all(axis=1)
    near = finite & (np.abs(np.where(np.isfinite(xyz), xyz, 0)) <= bound).all(axis=1)
    try:
        loaded = scans.load_scan(path, max_coordinate=bound)
    except SsfError as err:
        assert not near.any() and "no point with finite x, y, z" in one_line(err)
        return
    assert (loaded.total, loaded.non_finite, loaded.too_far) == (len(xyz), int((~finite).sum()), int((finite & ~near).sum()))
    np.testing.assert_array_equal(loaded.points[:, :3], xyz[near])


@SUITE
@given(
    array=st.one_of(
        hnp.arrays(hnp.scalar_dtypes(), hnp.array_shapes(max_dims=3, max_side=5)),
        hnp.arrays(hnp.unicode_string_dtypes(max_len=3) | hnp.byte_string_dtypes(max_len=3), (4, 3)),
        hnp.arrays(np.dtype([("x", "f4"), ("y", "U2"), ("z", "c8")]), (3,)),
    ),
    suffix=st.sampled_from([".npy", ".bin"]),
)
def test_wrong_dtypes_are_refused_in_one_line(tmp_path_factory, array, suffix):
    path = tmp_path_factory.getbasetemp() / f"dtype{suffix}"
    if suffix == ".npy":
        np.save(path, array)
    else:
        path.write_bytes(array.tobytes())
    points = refused_or(lambda: scans.read_scan(path, warn=None))
    if points is not None:
        assert points.dtype == np.float32 and finite_within(points, scans.MAX_COORDINATE_M)
    loaded = refused_or(lambda: read_array(path.with_suffix(".npy") if suffix == ".npy" else path, what="mask"))
    if loaded is not None:
        assert loaded.dtype.kind in "biuf" and loaded.dtype.names is None


@pytest.mark.parametrize("storage", sorted(bag_reader.SUFFIXES))
def test_every_bag_storage_answers_broken_files_in_one_line(tmp_path, bag_samples, storage):
    assert storage in bag_samples, f"add a valid {storage} sample to tests/bad_input/conftest.py"
    path = tmp_path / f"bag{storage}"

    @SUITE
    @given(content=mutations(bag_samples[storage]))
    def check(content: bytes) -> None:
        path.write_bytes(content)

        def read_everything():
            with bag_reader.open_bag(path) as bag:
                found = [bag.decode(message) for message in bag.messages()]
                timeline = bag.timeline
                assert timeline.messages >= len(found) - timeline.outside
                return found

        refused_or(read_everything)

    check()


def test_broken_bag_metadata_is_one_line(tmp_path, bag_samples):
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "bag_0.mcap").write_bytes(bag_samples[".mcap"])

    @SUITE
    @given(content=yaml_documents(bag_samples["metadata.yaml"].decode()))
    def check(content: bytes) -> None:
        (folder / "metadata.yaml").write_bytes(content)
        refused_or(lambda: bag_reader.open_bag(folder).close())

    check()


@SUITE
@given(text=st.one_of(st.text(max_size=200), yaml_documents("- {history: 1, depth: 10}").map(
    lambda raw: raw.decode("utf-8", "replace"))))
def test_offered_qos_text_is_parsed_or_refused_in_one_line(text):
    refused_or(lambda: parse_profiles(text, "bag: topic /x"))


CLOUD = messages.serialize(
    pointcloud.xyz_to_cloud(
        np.random.default_rng(1).normal(size=(16, 3)).astype(np.float32), messages.header(5, "lidar"),
        intensity=np.ones(16, np.float32),
    ),
    "sensor_msgs/msg/PointCloud2",
)  # fmt: skip


@SUITE
@given(data=mutations(CLOUD, max_random=512))
def test_broken_pointcloud2_messages_are_one_line(data):
    def decode():
        cloud = pointcloud.decode_cloud(messages.deserialize(data, "sensor_msgs/msg/PointCloud2"))
        assert np.isfinite(cloud.xyz).all()
        return cloud

    refused_or(decode)


def test_strict_json_of_every_float(tmp_path):
    from ssf_common.jsonio import dumps_strict

    @SUITE
    @given(value=st.recursive(
        st.floats() | st.integers() | st.text(max_size=5) | st.none(),
        lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
        max_leaves=10,
    ))  # fmt: skip
    def check(value) -> None:
        json.loads(dumps_strict(value), parse_constant=lambda name: pytest.fail(f"{name} in strict JSON"))

    check()
