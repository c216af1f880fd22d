"""Shared edge checks: output paths before the work, strict JSON, finite numbers and seeds, typed arrays."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ssf_common.arrays import read_array
from ssf_common.checks import SEED_MAX, require_finite, require_seed
from ssf_common.errors import ConfigError, DataError
from ssf_common.jsonio import dumps_strict, write_json
from ssf_common.paths import check_writable, check_writable_dir


def strict_loads(text: str):
    """json.loads that refuses NaN and Infinity, as strict parsers do."""
    return json.loads(text, parse_constant=lambda name: pytest.fail(f"non-standard JSON constant {name}"))


def test_writable_paths_pass_and_leave_nothing_behind(tmp_path):
    target = tmp_path / "new" / "deeper" / "result.json"
    assert check_writable(target, "summary") == target
    assert target.parent.is_dir() and not target.exists()
    existing = tmp_path / "kept.json"
    existing.write_text("old")
    check_writable(existing)
    assert existing.read_text() == "old"  # checked, not truncated
    assert check_writable_dir(tmp_path / "out" / "run") == tmp_path / "out" / "run"
    assert list((tmp_path / "out" / "run").iterdir()) == []


def a_file(folder: Path) -> Path:
    (folder / "file.txt").write_text("")
    return folder / "file.txt"


@pytest.mark.parametrize(
    ("make", "fragment"),
    [
        (lambda tmp: Path("/proc/nope/x.json"), "cannot create the folder"),
        (lambda tmp: a_file(tmp) / "x.json", "cannot create the folder"),
        (lambda tmp: tmp, "is a folder"),
        (lambda tmp: Path("/proc/version"), "cannot write"),
    ],
)
def test_unwritable_paths_fail_in_one_line(tmp_path, make, fragment):
    path = make(tmp_path)
    with pytest.raises(DataError) as caught:
        check_writable(path, "episode summary")
    assert fragment in str(caught.value) and str(path) in str(caught.value) and "\n" not in str(caught.value)


def test_unwritable_folders_fail_in_one_line(tmp_path):
    (tmp_path / "plain").write_text("")
    with pytest.raises(DataError, match="is a file"):
        check_writable_dir(tmp_path / "plain")
    with pytest.raises(DataError, match="cannot create the folder"):
        check_writable_dir(Path("/proc/nope/out"))


def test_strict_json_turns_nan_and_infinity_into_null(tmp_path):
    payload = {"min_clearance": math.inf, "nan": float("nan"), "np": np.float32("-inf"), "ok": np.float64(1.5),
               "count": np.int64(3), "flag": np.bool_(True), "list": np.array([1.0, np.nan]), "path": tmp_path,
               "nested": [{"x": -math.inf}], 2: "int key"}  # fmt: skip
    text = dumps_strict(payload)
    assert "Infinity" not in text and "NaN" not in text
    back = strict_loads(text)
    assert back["min_clearance"] is None and back["nan"] is None and back["np"] is None
    assert back["ok"] == 1.5 and back["count"] == 3 and back["flag"] is True and back["list"] == [1.0, None]
    assert back["path"] == str(tmp_path) and back["nested"] == [{"x": None}] and back["2"] == "int key"
    written = write_json(tmp_path / "out.json", payload)
    assert strict_loads(written.read_text()) == back
    with pytest.raises(TypeError, match=r"\$\.bad: object has no JSON form"):
        dumps_strict({"bad": object()})


def test_strict_json_write_failure_is_one_line(tmp_path):
    with pytest.raises(DataError, match="cannot write"):
        write_json(tmp_path / "missing" / "x.json", {"a": 1})


@pytest.mark.parametrize(
    ("value", "bounds", "fragment"),
    [
        (math.inf, {}, "finite"),
        (math.nan, {"at_least": 0}, "finite"),
        (-1.0, {"above": 0.0}, "must be above 0"),
        (0.0, {"above": 0.0}, "must be above 0"),
        (-5, {"at_least": 0.0}, "at least 0"),
        (11, {"at_most": 10}, "at most 10"),
        ("soon", {}, "must be a number"),
    ],
)
def test_require_finite_names_the_flag(value, bounds, fragment):
    with pytest.raises(ConfigError, match=fragment) as caught:
        require_finite(value, "--duration", **bounds)
    assert str(caught.value).startswith("--duration ")


def test_require_finite_passes_good_values():
    assert require_finite(3, "--rate", above=0) == 3.0
    assert require_finite("2.5", "--rate", at_least=0, at_most=10) == 2.5


def test_seeds_are_integers_numpy_takes():
    assert require_seed(0) == 0 and require_seed(np.int64(SEED_MAX)) == SEED_MAX
    for bad in (-7, SEED_MAX + 1, 1.5, True, "3", None):
        with pytest.raises(ConfigError, match=f"--seed must be an integer from 0 to {SEED_MAX}"):
            require_seed(bad)


def test_arrays_are_read_with_their_dtype_shape_and_values_checked(tmp_path):
    np.save(tmp_path / "mask.npy", np.array([0.0, 1.0, 0.5], dtype=np.float32))
    np.testing.assert_array_equal(read_array(tmp_path / "mask.npy", what="mask", ndim=1), [0.0, 1.0, 0.5])
    (tmp_path / "mask.txt").write_text("0 1\n1 0\n")
    assert read_array(tmp_path / "mask.txt", shape=(None, 2)).shape == (2, 2)
    np.save(tmp_path / "words.npy", np.array(["moving", "static"]))
    np.save(tmp_path / "objects.npy", np.array([1, None], dtype=object), allow_pickle=True)
    np.save(tmp_path / "nan.npy", np.array([0.0, np.nan]))
    np.save(tmp_path / "table.npy", np.zeros((3, 2)))
    raw = (tmp_path / "table.npy").read_bytes()
    (tmp_path / "cut.npy").write_bytes(raw[:-7])
    (tmp_path / "binary.txt").write_bytes(bytes(range(128, 256)))
    (tmp_path / "words.txt").write_text("1 2 moving\n")
    cases = [
        ("words.npy", {}, "holds str values (<U6); expected bool/int/uint/float"),
        ("objects.npy", {}, "never unpickled"),
        ("nan.npy", {"finite": True}, "holds 1 NaN or infinite values of 2"),
        ("table.npy", {"ndim": 1}, "has 2 dimensions (3, 2); expected 1"),
        ("table.npy", {"shape": (None, 3)}, "has shape (3, 2); expected (N, 3)"),
        ("cut.npy", {}, "truncated: the header promises 48 bytes of data, the file holds 41"),
        ("binary.txt", {}, "not text (byte 0x80 at offset 0)"),
        ("words.txt", {}, "not whitespace-separated numbers"),
        ("missing.npy", {}, "no such mask file"),
    ]
    for name, checks, fragment in cases:
        with pytest.raises(DataError) as caught:
            read_array(tmp_path / name, what="mask", **checks)
        assert fragment in str(caught.value) and name in str(caught.value), name
        assert "\n" not in str(caught.value)
