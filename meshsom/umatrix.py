"""U-matrix pictures (matplotlib ``Figure`` objects, no pyplot: a notebook's backend is left alone).

On a toroidal map the picture shows the map itself with a thin band of its wrapped continuation
on every side (``wrap`` cells, drawn faint, the map's border dashed), so that clusters crossing
the edge are seen as connected while the map keeps almost all of the panel. Colours span the
1st-99th percentile of the values (:data:`meshsom.figures.PERCENTILES`), so a few outlying cells
do not flatten the rest; the colour bar says so. Every file is written as PNG and SVG.
"""

from __future__ import annotations

import os

import numpy as np

from meshsom.figures import PERCENTILES, clip_note, fit_text, new_figure, robust_limits, save_figure
from meshsom.metrics import TOPOLOGIES, u_matrix

__all__ = ["UMAT_LABEL", "WRAP_FRACTION", "draw_u_matrix", "render_map", "render_u_matrix", "u_matrix_figure",
           "wrap_cells"]

#: Width of the wrapped band on a toroidal picture, as a share of the map's shorter side.
WRAP_FRACTION = 0.06
#: Colour-bar label of a U-matrix (standardized fold vectors).
UMAT_LABEL = "mean distance to neighbours (standardized units)"
#: Opacity of the wrapped band.
FAINT_ALPHA = 0.45


def wrap_cells(rows: int, cols: int, fraction: float = WRAP_FRACTION) -> int:
    """Cells of wrapped band shown on each side of a toroidal ``rows x cols`` map (at least 1)."""
    return max(1, int(round(fraction * min(rows, cols))))


def draw_u_matrix(ax, umat, topology: str = "toroidal", cmap: str = "viridis", faint_alpha: float = FAINT_ALPHA,
                  frame_width: float = 1.2, vmin: float | None = None, vmax: float | None = None,
                  wrap: int | None = None):
    """Draw a U-matrix into a matplotlib axis.

    Toroidal: the map with a band of ``wrap`` wrapped cells on every side, faint, and the map's
    frame dashed. The caller sets title, labels and colour bar.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    umat : (rows, cols) float
        From :func:`meshsom.metrics.u_matrix`.
    topology : {"toroidal", "planar"}
    cmap : str
    faint_alpha : float
        Opacity of the wrapped band.
    frame_width : float
        Line width of the dashed map frame.
    vmin, vmax : float or None
        Colour limits; None: :func:`meshsom.figures.robust_limits` of ``umat``.
    wrap : int or None
        Cells of wrapped band per side; None: :func:`wrap_cells`; 0: none.

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
    from matplotlib.patches import Rectangle

    rows, cols = umat.shape
    lo, hi = robust_limits(umat)
    vmin = lo if vmin is None else vmin
    vmax = hi if vmax is None else vmax
    own = (-0.5, cols - 0.5, rows - 0.5, -0.5)
    w = 0 if topology == "planar" else (wrap_cells(rows, cols) if wrap is None else int(wrap))
    if w < 0:
        raise ValueError(f"wrap must be >= 0 cells, received {wrap}")
    w = min(w, rows, cols)
    if w:
        band = np.pad(umat, w, mode="wrap")
        ax.imshow(band, cmap=cmap, vmin=vmin, vmax=vmax, alpha=faint_alpha, interpolation="nearest",
                  extent=(-w - 0.5, cols + w - 0.5, rows + w - 0.5, -w - 0.5))
    image = ax.imshow(umat, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest", extent=own)
    if w:
        ax.add_patch(Rectangle((-0.5, -0.5), cols, rows, fill=False, linestyle="--", linewidth=frame_width,
                               edgecolor="white"))
    ax.set_xlim(-w - 0.5, cols + w - 0.5)
    ax.set_ylim(rows + w - 0.5, -w - 0.5)
    return image


def u_matrix_figure(umat, topology: str = "toroidal", title: str = "U-matrix", cmap: str = "viridis",
                    faint_alpha: float = FAINT_ALPHA, label: str = UMAT_LABEL, width: float = 7.5):
    """A one-panel U-matrix figure with a labelled colour bar.

    Parameters
    ----------
    umat : (rows, cols) float
    topology : {"toroidal", "planar"}
    title : str
        Wrapped to the figure's width; the map size and the wrap band are named below it.
    label : str
        What the values are (the colour bar's label; the percentile clip is added).
    width : float
        Figure width in inches (the height follows the map's aspect).

    Returns
    -------
    matplotlib.figure.Figure
    """
    rows, cols = np.shape(umat)
    w = wrap_cells(rows, cols) if topology == "toroidal" else 0
    aspect = (rows + 2 * w) / (cols + 2 * w)
    fig = new_figure((width, min(12.0, max(3.5, 0.82 * width * aspect + 1.3))))
    ax = fig.add_subplot()
    image = draw_u_matrix(ax, umat, topology, cmap, faint_alpha)
    note = (f"{rows} x {cols} torus; faint band: {w} wrapped cell{'s' if w > 1 else ''} per side"
            if topology == "toroidal" else f"{rows} x {cols} planar")
    ax.set_title(fit_text(f"{title}\n{note}", 0.8 * width, 10), fontsize=10)
    ax.set_xlabel("column")
    ax.set_ylabel("row")
    fig.colorbar(image, ax=ax, extend="both", shrink=0.9,
                 label=fit_text(f"{label}; {clip_note(PERCENTILES)}", 0.8 * fig.get_figheight(), 9))
    return fig


def render_u_matrix(umat, path: str | os.PathLike, topology: str = "toroidal", title: str = "U-matrix",
                    cmap: str = "viridis", faint_alpha: float = FAINT_ALPHA, dpi: int = 120) -> str:
    """Write a U-matrix as ``path`` (PNG) and the same stem ``.svg`` (:func:`u_matrix_figure`).

    Parameters
    ----------
    umat : (rows, cols) float
        From :func:`meshsom.metrics.u_matrix`.
    path : path
        The PNG; the SVG is written beside it.
    topology : {"toroidal", "planar"}
    faint_alpha : float
        Opacity of the wrapped band.

    Returns
    -------
    str
        The PNG's path (the SVG is ``Path(png).with_suffix(".svg")``).
    """
    fig = u_matrix_figure(umat, topology, title, cmap, faint_alpha)
    return save_figure(fig, path, dpi)[0]


def render_map(W, rows: int, cols: int, path: str | os.PathLike, topology: str = "toroidal", **kwargs) -> str:
    """Compute the U-matrix of prototypes ``W (rows*cols, D)`` and render it (see :func:`render_u_matrix`)."""
    return render_u_matrix(u_matrix(W, rows, cols, topology), path, topology=topology, **kwargs)
