"""Hostile input for the bad-input suite: Hypothesis strategies, valid samples to break, and the one-line oracle."""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from ssf_common.errors import SsfError

# Reproducible in CI (derandomize: the same examples every run), no wall-clock deadline on a shared machine.
# SSF_BAD_INPUT_EXAMPLES=2000 SSF_BAD_INPUT_RANDOM=1 explores further by hand; CI runs the fixed 40.
SUITE = settings(
    max_examples=int(os.environ.get("SSF_BAD_INPUT_EXAMPLES", "40")),
    deadline=None,
    derandomize=not os.environ.get("SSF_BAD_INPUT_RANDOM"),
    database=None,
    print_blob=False,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large],
)
MAX_MESSAGE_CHARS = 2000


def one_line(err: BaseException) -> str:
    """The error's message, checked to be one non-empty line of reasonable length."""
    text = str(err)
    assert isinstance(err, SsfError), f"{type(err).__name__} escaped: {text}"
    assert text and "\n" not in text and "\r" not in text, repr(text)
    assert len(text) <= MAX_MESSAGE_CHARS, f"{len(text)} characters"
    return text


def refused_or(call: Callable[[], Any]) -> Any:
    """The call's result, or None when it raised an SsfError with a one-line message; anything else escapes."""
    try:
        return call()
    except SsfError as err:
        one_line(err)
        return None


# Bytes


def _overwrite(sample: bytes, at: int, junk: bytes) -> bytes:
    return sample[:at] + junk + sample[at + len(junk) :]


def _insert(sample: bytes, at: int, junk: bytes) -> bytes:
    return sample[:at] + junk + sample[at:]


def mutations(sample: bytes, max_random: int = 2048) -> st.SearchStrategy[bytes]:
    """A valid file broken every usual way: random bytes, cut short, bytes overwritten, junk spliced in."""
    size = len(sample)
    return st.one_of(
        st.binary(max_size=max_random),
        st.integers(0, size).map(lambda cut: sample[:cut]),
        st.tuples(st.integers(0, max(size - 1, 0)), st.binary(min_size=1, max_size=24)).map(
            lambda args: _overwrite(sample, *args)
        ),
        st.tuples(st.integers(0, size), st.binary(min_size=1, max_size=64)).map(lambda args: _insert(sample, *args)),
        st.tuples(st.integers(0, size), st.sampled_from([b"\xff\xfe", b"\x00", b"\xc3\x28", b"\xe9"])).map(
            lambda args: _insert(sample, *args)
        ),
    )


# YAML

KNOWN_BAD_YAML = [
    "agents: &a {count: 10, x: *a}",
    "a: &a [*a]",
    "x: " + "[" * 500 + "]" * 500,
    "x: " + "{a: " * 300 + "1" + "}" * 300,
    "a: &a [1,1,1,1,1,1,1,1,1,1]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a,*a]\nc: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
    "d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c,*c]\ne: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d,*d]\nf: [*e,*e,*e,*e,*e,*e,*e,*e]",
    "a: 1\na: 2",
    "x: !!python/object/apply:os.system ['true']",
    "x: " + "9" * 5000,
    "when: 2001-13-45",
    "--- 1\n--- 2",
    "a: [1,",
    "a: *undefined",
    "a: \x00",
    "\ufeff\ufeff: 1",
    "x: !!binary '!!!'",
    "? [1, 2]\n: 3",
    "- - - -",
    "x: .nan\ny: -.inf\nz: 1e400",
]

_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
)  # fmt: skip
yaml_values = st.recursive(
    _scalars, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=12,
)  # fmt: skip


def yaml_documents(sample: str) -> st.SearchStrategy[bytes]:
    """YAML a reader may be handed: known attacks, arbitrary text, wrong shapes, and the sample broken."""
    return st.one_of(
        st.sampled_from(KNOWN_BAD_YAML).map(str.encode),
        st.text(max_size=300).map(lambda text: text.encode("utf-8", "surrogatepass")),
        yaml_values.map(lambda value: yaml.safe_dump(value).encode()),
        st.dictionaries(st.sampled_from(_top_keys(sample)), yaml_values, max_size=3).map(
            lambda value: yaml.safe_dump(value).encode()
        ),
        mutations(sample.encode(), max_random=512),
    )


def _top_keys(sample: str) -> list[str]:
    keys = list(yaml.safe_load(sample) or {}) or ["x"]
    return [*map(str, keys), "unknown_key"]


# Numbers and flags

NON_FINITE = ["nan", "inf", "-inf", "NaN", "Infinity", "1e400", "-1e400"]


def not_positive() -> st.SearchStrategy[str]:
    """Text argparse reads as a float, none of it a positive finite number."""
    return st.one_of(
        st.sampled_from(NON_FINITE + ["0", "-0.0"]),
        st.floats(max_value=0.0, allow_nan=False, allow_infinity=False).map(repr),
    )


def negative() -> st.SearchStrategy[str]:
    """Floats argparse accepts that no delay or rate may be: negative or not finite."""
    return st.one_of(
        st.sampled_from(NON_FINITE),
        st.floats(max_value=-1e-9, allow_nan=False, allow_infinity=False).map(repr),
    )


def bad_seeds() -> st.SearchStrategy[str]:
    """Integers no numpy generator takes as a seed (the demo's -1 means 'the scenario's own')."""
    return st.one_of(st.integers(max_value=-2), st.integers(min_value=2**32, max_value=2**80)).map(str)


def bad_overrides() -> st.SearchStrategy[str]:
    """NAME:=VALUE items that are malformed in name, separator or value."""
    return st.one_of(
        st.sampled_from(["novalue", "=3", ":=3", "a b:=1", "a..b:=1", ".a:=1", "a:=", "a=  ", "1a:=2"]),
        st.sampled_from(["[1,", "{a: ", "*x", "&a [*a]", "'open", "\"open", "!!python/name:os.system ''", "@x"]).map(
            lambda value: f"agents.count:={value}"
        ),
    )


def unwritable_paths(folder: Path) -> list[Path]:
    """Output paths no process can write: under a file, inside /proc, a folder itself."""
    blocker = folder / "a_file"
    blocker.write_text("")
    return [Path("/proc/nope/out.json"), blocker / "out.json", folder]


def finite_within(points: np.ndarray, bound: float) -> bool:
    """Whether every x, y, z is finite and within the bound (intensity is not a coordinate)."""
    xyz = points[:, :3]
    return bool(np.isfinite(xyz).all() and (np.abs(xyz) <= bound).all())


def is_finite_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False
