"""The picture of docs/sensors.md's sweep section: a pair of consecutive KITTI .bin scans from above, as swept and
deskewed, with the moving objects `ssf seg estimate` reported both ways and the true movers of the export.

    python scripts/sweep_pair_picture.py EXPORT PAIR OUT.png

EXPORT: an `ssf dataset export` folder, with obs_PAIR_true.json and obs_PAIR_false.json (`ssf seg estimate
--obstacles`, deskewed and not) beside its pairs.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ssf_common.dataset.pairs import read_pair  # noqa: E402
from ssf_common.geometry.sweep import deskew  # noqa: E402
from ssf_common.render.figures import save_figure  # noqa: E402
from ssf_common.scans import read_scan_with_time  # noqa: E402


def main(export: Path, pair_index: int, out: Path) -> None:
    """Draw the pair: the whole scene with the objects reported, and a close look at a near wall, swept and deskewed."""
    pair = read_pair(export / "pairs" / f"{pair_index:06d}.npz")
    scans = sorted((export / "sequence" / "velodyne").glob("*.bin"))
    first = read_scan_with_time(scans[pair_index], warn=None)
    straight = deskew(first.points[:, :3], first.time, pair.ego, 0.1)
    figure, (whole, near) = plt.subplots(1, 2, figsize=(14, 6.5), gridspec_kw={"width_ratios": [1.6, 1]})
    keep = np.linalg.norm(pair.pc1[:, :2], axis=1) < 62
    near2 = np.linalg.norm(pair.pc2[:, :2], axis=1) < 62
    whole.scatter(*pair.pc2[near2, :2].T, s=0.1, c="#9ecae1", label="scan t+1")
    whole.scatter(*pair.pc1[keep, :2].T, s=0.1, c="0.45", label="scan t")
    whole.scatter(*pair.pc1[pair.dynamic1, :2].T, s=3, c="tab:orange", label="true movers (scan t)")
    for deskewed, style in (("true", dict(ec="tab:green", lw=1.6)), ("false", dict(ec="tab:red", lw=1.0, ls="--"))):
        obstacles = json.loads((export / f"obs_{pair_index}_{deskewed}.json").read_text())["obstacles"]
        for item in (o for o in obstacles if o["moving"]):
            x, y = item["centre"][:2]
            length, width = item["size"][:2]
            box = matplotlib.patches.Rectangle((x - length / 2, y - width / 2), length, width,
                                               angle=np.degrees(item["yaw"]), rotation_point="center", fill=False,
                                               **style)
            whole.add_patch(box)
            speed = np.linalg.norm(item["velocity"][:2])
            if deskewed == "true":
                whole.annotate(f"{speed:.1f} m/s", (x, y + width), fontsize=8, color="tab:green")
    whole.plot([], [], c="tab:green", label="moving object, deskewed")
    whole.plot([], [], c="tab:red", ls="--", label="moving object, as swept")
    whole.set_aspect("equal")
    whole.set_xlim(-62, 62)
    whole.set_ylim(-40, 40)
    whole.set_title(f"pair {pair_index} from above (sensor frame of scan t, ego at "
                    f"{np.linalg.norm(pair.ego[:3, 3]) / 0.1:.1f} m/s along +x)")
    whole.legend(loc="lower left", markerscale=8, fontsize=8)
    side = (np.abs(first.points[:, :2]) < 25).all(axis=1) & (first.points[:, 2] > 0.5)
    near.scatter(*first.points[side, :2].T, s=0.4, c="tab:red",
                 label="as swept (each column from where the sensor was)")
    near.scatter(*straight[side, :2].T, s=0.4, c="tab:green", label="deskewed to the sweep's middle")
    near.set_aspect("equal")
    near.set_title("structure above 0.5 m within 25 m")
    near.legend(loc="lower left", markerscale=10, fontsize=8)
    figure.tight_layout()
    save_figure(figure, out, dpi=110)


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]), Path(sys.argv[3]))
