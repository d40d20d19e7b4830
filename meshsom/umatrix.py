"""U-matrix rendering to PNG (matplotlib, Agg backend, imported lazily).

On a toroidal map the picture shows the map tiled 2 x 2: the central copy in full
colour, the wrapped copies faint, and the map's own border as a dashed frame, so that
clusters crossing the wrap are seen as connected.
"""

from __future__ import annotations

import os

import numpy as np

from meshsom.metrics import TOPOLOGIES, u_matrix


def _pyplot():
    try:
        import matplotlib
    except ImportError:  # pragma: no cover - matplotlib is a dependency
        raise ImportError("rendering the U-matrix needs matplotlib: pip install matplotlib") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_u_matrix(ax, umat, topology: str = "toroidal", cmap: str = "viridis", faint_alpha: float = 0.35,
                  frame_width: float = 1.2):
    """Draw a U-matrix into a matplotlib axis.

    Toroidal: the map tiled 2 x 2, centred on the original (half a map of wrap on each side),
    the wrapped copies faint and the map frame dashed. The caller sets title and labels.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    umat : (rows, cols) float
        From :func:`meshsom.metrics.u_matrix`.
    topology : {"toroidal", "planar"}
    faint_alpha : float
        Opacity of the wrapped copies.
    frame_width : float
        Line width of the dashed map frame.

    Returns
    -------
    matplotlib.image.AxesImage
        The image of the map itself (for a colour bar).
    """
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {', '.join(TOPOLOGIES)}; received {topology!r}")
    umat = np.asarray(umat, np.float64)
    if umat.ndim != 2:
        raise ValueError(f"umat must be a (rows, cols) array, received shape {umat.shape}")
    plt = _pyplot()
    rows, cols = umat.shape
    vmin, vmax = float(np.nanmin(umat)), float(np.nanmax(umat))
    if topology == "planar":
        return ax.imshow(umat, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
    r0, c0 = rows // 2, cols // 2
    extent = (-c0 - 0.5, 2 * cols - c0 - 0.5, 2 * rows - r0 - 0.5, -r0 - 0.5)
    tiled = np.roll(np.roll(np.tile(umat, (2, 2)), r0, axis=0), c0, axis=1)
    ax.imshow(tiled, cmap=cmap, vmin=vmin, vmax=vmax, alpha=faint_alpha, extent=extent, interpolation="nearest")
    image = ax.imshow(umat, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest",
                      extent=(-0.5, cols - 0.5, rows - 0.5, -0.5))
    ax.add_patch(plt.Rectangle((-0.5, -0.5), cols, rows, fill=False, linestyle="--", linewidth=frame_width,
                               edgecolor="white"))
    ax.set_xlim(extent[0], extent[0] + 2 * cols)
    ax.set_ylim(extent[2], extent[3])
    return image


def render_u_matrix(umat, path: str | os.PathLike, topology: str = "toroidal", title: str = "U-matrix",
                    cmap: str = "viridis", faint_alpha: float = 0.35, dpi: int = 120) -> str:
    """Write a U-matrix as a PNG (drawn by :func:`draw_u_matrix`).

    Parameters
    ----------
    umat : (rows, cols) float
        From :func:`meshsom.metrics.u_matrix`.
    path : path
    topology : {"toroidal", "planar"}
    faint_alpha : float
        Opacity of the wrapped copies.

    Returns
    -------
    str
        The path written.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 6) if topology == "planar" else (9, 7.5))
    try:
        image = draw_u_matrix(ax, umat, topology, cmap, faint_alpha)
        rows, cols = np.shape(umat)
        ax.set_title(f"{title} ({rows} x {cols} torus; faint: wrapped copies)" if topology == "toroidal"
                     else f"{title} ({rows} x {cols} planar)")
        ax.set_xlabel("column")
        ax.set_ylabel("row")
        fig.colorbar(image, ax=ax, label="mean distance to neighbours")
        fig.tight_layout()
        fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)
    return str(path)


def render_map(W, rows: int, cols: int, path: str | os.PathLike, topology: str = "toroidal", **kwargs) -> str:
    """Compute the U-matrix of prototypes ``W (rows*cols, D)`` and render it (see :func:`render_u_matrix`)."""
    return render_u_matrix(u_matrix(W, rows, cols, topology), path, topology=topology, **kwargs)
