"""The memory's figure: where its targets are, and ``T`` over the target region.

Two panels from above (x, y) and from the side (x, z) of the base frame: each stored
motion's target point, coloured by its ``T`` (s), one marker per start (station). A
planar arm's memory has one panel. Written by ``memory figure``; matplotlib is imported
here only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["coverage_figure"]


def coverage_figure(rows: list[dict], output) -> Path:
    """Draw the coverage of ``rows`` (:meth:`MotionStore.summary`) into ``output`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    targets = np.array([r["target_point"] for r in rows])
    starts = np.array([r["start_point"] for r in rows])
    T = np.array([r["T"] for r in rows])
    labels = {tuple(np.round(s, 3)) for s in starts}
    markers = dict(zip(sorted(labels), "osD^v<>phX*" * 10, strict=False))
    views = [(0, 1, "x (m)", "y (m)", "from above")]
    if targets.shape[1] == 3:
        views.append((0, 2, "x (m)", "z (m)", "from the side"))
    fig, axes = plt.subplots(1, len(views), figsize=(5.5 * len(views), 4.5), squeeze=False)
    for ax, (i, j, xl, yl, title) in zip(axes[0], views, strict=True):
        for start, marker in markers.items():
            mask = np.array([tuple(np.round(s, 3)) == start for s in starts])
            sc = ax.scatter(targets[mask, i], targets[mask, j], c=T[mask], marker=marker,
                            vmin=T.min(), vmax=T.max(), cmap="viridis", s=24,
                            label=f"start {np.round(start, 2).tolist()}")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_title(f"{len(rows)} stored motions, {title}")
        ax.set_aspect("equal", adjustable="datalim")
    fig.colorbar(sc, ax=axes[0].tolist(), label="T (s)")
    axes[0][0].legend(fontsize=7, loc="best")
    output = Path(output)
    fig.savefig(output, dpi=110)
    plt.close(fig)
    return output
