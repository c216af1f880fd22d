"""The one YAML reader and NAME:=VALUE overrides: every failure is one ConfigError line naming file and place."""

from __future__ import annotations

import math

import pytest
from pydantic import Field

from ssf_common.config import (
    MAX_YAML_BYTES,
    MAX_YAML_DEPTH,
    Section,
    build,
    current_name,
    dump,
    load_yaml_text,
    parse_overrides,
    read_yaml,
)
from ssf_common.errors import ConfigError


class Sweep(Section):
    renamed = {"dt": "scan_period"}
    scan_period: float = Field(0.1, gt=0)


class Sensor(Section):
    renamed = {"sweep_settings": "sweep"}
    sweep: Sweep = Sweep()
    rows: int = 64


def test_a_renamed_field_reads_under_its_old_name_in_files_flags_and_nested_sections():
    """Configs written before a rename still load: the old name is read as the new one in any layer, a later layer
    wins whichever name it uses, and giving both names at once is one clear error."""
    assert build(Sweep, {"dt": 0.05}).scan_period == 0.05
    assert Sweep(dt=0.05).scan_period == 0.05 and Sweep.model_validate({"dt": 0.2}).scan_period == 0.2
    assert build(Sensor, {"sweep_settings": {"dt": 0.05}}).sweep.scan_period == 0.05
    assert build(Sensor, {"sweep.scan_period": 0.2}, {"sweep.dt": 0.05}).sweep.scan_period == 0.05
    assert build(Sensor, {"sweep.dt": 0.05}, {"sweep": {"scan_period": 0.2}}).sweep.scan_period == 0.2
    with pytest.raises(ConfigError, match="'dt' is the old name of 'scan_period'"):
        build(Sensor, {"sweep": {"dt": 0.05, "scan_period": 0.2}})
    with pytest.raises(ConfigError, match="scan_period"):
        build(Sweep, {"dt": -1.0})  # the value is checked under the name it has now
    assert current_name(Sensor, "sweep_settings.dt") == "sweep.scan_period" and current_name(Sensor, "rows") == "rows"
    assert "dt" not in dump(build(Sweep, {"dt": 0.05}))  # written back under the name it has now


class Limits(Section):
    speed: float = Field(1.0, gt=0)
    points: list[tuple[float, float]] = [(0.0, 0.0)]


def test_reads_mappings_aliases_merge_keys_and_yaml_1_2_floats(tmp_path):
    path = tmp_path / "ok.yaml"
    path.write_text("base: &b {count: 10}\nother: {<<: *b, x: 1}\nlist: [*b, *b]\nfar: 1e30\nnear: -2.5E-3\n")
    data = read_yaml(path)
    assert data["other"] == {"count": 10, "x": 1}
    assert data["list"] == [{"count": 10}, {"count": 10}]
    assert data["far"] == 1e30 and data["near"] == -2.5e-3  # PyYAML alone reads both as strings


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("agents: &a {count: 10, x: *a}", "recursive alias"),
        ("c: &c [1, {d: [*c]}]", "recursive alias"),
        ("x: " + "[" * (MAX_YAML_DEPTH + 5) + "]" * (MAX_YAML_DEPTH + 5), f"nested deeper than {MAX_YAML_DEPTH}"),
        ("a: &a [1,1,1,1,1,1,1,1,1,1]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a,*a]\nc: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
         "d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c,*c]\ne: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d,*d]\nf: [*e,*e,*e,*e,*e,*e]",
         "expands to more than"),
        ("speed: 1\nspeed: 2", "key 'speed' appears twice"),
        ("speed: [1,", "not valid YAML at line 1"),
        ("x: !!python/object/apply:os.system ['true']", "not valid YAML"),
        ("x: " + "9" * 5000, "not valid YAML"),
        ("when: 2001-13-45", "not valid YAML"),
        ("a: 1\n--- \nb: 2", "not valid YAML at line 2"),
        ("a: \x00", "unacceptable character #x0000"),
    ],
)
def test_hostile_yaml_is_one_line(tmp_path, text, fragment):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as caught:
        read_yaml(path)
    message = str(caught.value)
    assert fragment in message and str(path) in message and "\n" not in message


def test_files_that_are_not_utf8_text_name_the_byte(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("name: caf\xe9\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin1.yaml: not UTF-8 text \(byte 0xe9 at offset 9\)"):
        read_yaml(path)


def test_size_and_kind_of_file_are_checked(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * MAX_YAML_BYTES + b"\n")
    with pytest.raises(ConfigError, match="too large"):
        read_yaml(big)
    with pytest.raises(ConfigError, match="not a regular file"):
        read_yaml(tmp_path)
    with pytest.raises(ConfigError, match="no such file"):
        read_yaml(tmp_path / "missing.yaml")
    listing = tmp_path / "list.yaml"
    listing.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="expected a mapping"):
        read_yaml(listing)


def test_sections_refuse_nan_and_infinity_and_name_the_field():
    for value in (".nan", ".inf", "-.inf"):
        with pytest.raises(ConfigError, match="field 'speed'"):
            build(Limits, {"speed": load_yaml_text(value, "v")})
    with pytest.raises(ConfigError, match=r"field 'points\.1\.0'"):
        build(Limits, {"points": [[0.0, 0.0], [math.nan, 1.0]]})


def test_a_value_and_a_section_of_the_same_name_conflict():
    with pytest.raises(ConfigError, match="'points' is a section"):
        build(Limits, {"points.x": 1, "points": 2})


def test_overrides_take_both_forms_and_yaml_values():
    assert parse_overrides(["a.b:=3", "c=[1, 2]", "d:=x=y", "e=a:=b", "f:=''", "g:=1e3"]) == {
        "a.b": 3, "c": [1, 2], "d": "x=y", "e": "a:=b", "f": "", "g": 1000.0,
    }  # fmt: skip
    assert parse_overrides(["a:=1", "a:=2"]) == {"a": 2}  # later wins


@pytest.mark.parametrize(
    ("item", "fragment"),
    [
        ("agents.count=[1,", "--set agents.count: not valid YAML"),
        ("novalue", "expects NAME:=VALUE"),
        ("=3", "expects NAME:=VALUE"),
        ("a b:=1", "is not a parameter name"),
        ("a..b:=1", "is not a parameter name"),
        ("a:=", "the value is empty"),
        ("a:=&x [*x]", "recursive alias"),
        ("a:=*nope", "undefined alias"),
    ],
)
def test_malformed_overrides_are_one_line(item, fragment):
    with pytest.raises(ConfigError) as caught:
        parse_overrides([item], "--set")
    assert fragment in str(caught.value) and "\n" not in str(caught.value)
