"""The bird's-eye error picture of a pair."""

import numpy as np
import pytest
from matplotlib.image import imread

from ssf_common.errors import DataError
from ssf_flow_node.core.estimator import make_estimator
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_eval.flow.plot import plot_pair


def test_plot_pair_writes_a_png_per_estimator(tmp_path):
    pair = synthetic_pair(seed=0, agents=2, points=2048)
    results = {name: make_estimator(name).estimate(pair.pc1, pair.pc2) for name in ("ego", "rigid")}
    path = plot_pair(pair, results, tmp_path / "pictures" / "pair.png", "synthetic")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = imread(path)
    single = imread(plot_pair(pair, {"ego": results["ego"]}, tmp_path / "one.png"))
    assert image.shape[1] > 1.3 * single.shape[1]  # one panel per estimator beside the truth
    colours = np.unique((image[..., :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 50  # points coloured by their error, not a blank canvas
    with pytest.raises(DataError, match="cannot write"):
        plot_pair(pair, results, path / "inside_a_file.png")
