"""Writing a matplotlib figure: one place that creates the folder, names an unwritable path in one line and closes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ssf_common.errors import DataError


def save_figure(figure: Any, path: str | Path, **options: Any) -> Path:
    """Write the figure to path (savefig options passed on) and close it; DataError names a path it cannot write."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        figure.savefig(path, **options)
    except OSError as err:
        raise DataError(f"{path}: cannot write the picture ({err.strerror})") from None
    finally:
        plt.close(figure)
    return path
