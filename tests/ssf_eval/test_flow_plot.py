"""The bird's-eye error picture of a pair."""

import pytest

from ssf_common.errors import DataError
from ssf_flow_node.core.estimator import make_estimator
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_eval.flow.plot import plot_pair


def test_plot_pair_writes_a_png_per_estimator(tmp_path):
    pair = synthetic_pair(seed=0, agents=2, points=2048)
    results = {name: make_estimator(name).estimate(pair.pc1, pair.pc2) for name in ("ego", "rigid")}
    path = plot_pair(pair, results, tmp_path / "pictures" / "pair.png", "synthetic")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(DataError, match="cannot write"):
        plot_pair(pair, results, path / "inside_a_file.png")
