"""Figure conventions shared by every picture meshsom draws: robust colour limits, titles that fit,
PNG and SVG side by side, and a check that no text is cut off.

Figures are ``matplotlib.figure.Figure`` objects built without pyplot, so drawing one never
switches or touches the backend of a notebook or a GUI session (matplotlib is imported lazily).
"""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np

__all__ = ["FORMATS", "PERCENTILES", "clip_note", "fit_text", "new_figure", "robust_limits", "save_figure",
           "texts_outside"]

#: Colour scales span these percentiles of the values shown; values outside take the end colours.
PERCENTILES = (1.0, 99.0)
#: Every figure is written in these formats, one file each, same stem.
FORMATS = ("png", "svg")
#: Width of an average character in units of the font size (for wrapping titles before drawing).
CHAR_WIDTH = 0.62


def _matplotlib():
    try:
        import matplotlib  # noqa: F401
        from matplotlib.figure import Figure
    except ImportError:  # pragma: no cover - matplotlib is a dependency
        raise ImportError("drawing figures needs matplotlib: pip install matplotlib") from None
    return Figure


def new_figure(figsize: tuple[float, float], layout: str | None = "constrained"):
    """A ``Figure`` of ``figsize`` inches with an Agg canvas attached, outside pyplot's state.

    Parameters
    ----------
    figsize : (2,) float
        Width and height in inches.
    layout : str or None
        Matplotlib layout engine; ``"constrained"`` keeps titles, labels and colour bars inside.
    """
    Figure = _matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=figsize, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def robust_limits(values, percentiles: tuple[float, float] = PERCENTILES) -> tuple[float, float]:
    """Colour limits from percentiles of the finite values, so that a few outliers do not set the scale.

    Parameters
    ----------
    values : array_like of float, any shape
        Every value that shares the scale (several panels: all of them together).
    percentiles : (2,) float
        Lower and upper percentile, in ``[0, 100]``.

    Returns
    -------
    (vmin, vmax) : float
        ``vmin < vmax`` always (a constant input gets a unit-wide range around it).
    """
    lo, hi = percentiles
    if not 0.0 <= lo < hi <= 100.0:
        raise ValueError(f"percentiles must satisfy 0 <= low < high <= 100, received {percentiles}")
    v = np.asarray(values, np.float64).ravel()
    v = v[np.isfinite(v)]
    if not len(v):
        return 0.0, 1.0
    vmin, vmax = (float(x) for x in np.percentile(v, [lo, hi]))
    if vmax <= vmin:
        return vmin - 0.5, vmin + 0.5
    return vmin, vmax


def clip_note(percentiles: tuple[float, float] = PERCENTILES) -> str:
    """How a colour bar was clipped, for its label: ``colour clipped to the 1-99th percentile``."""
    return f"colour clipped to the {percentiles[0]:g}-{percentiles[1]:g}th percentile"


def fit_text(text: str, width_inches: float, fontsize: float) -> str:
    """``text`` wrapped at word boundaries so that each line fits ``width_inches`` at ``fontsize`` points.

    Existing line breaks are kept; a single word longer than the width stays whole.
    """
    chars = max(8, int(width_inches * 72.0 / (fontsize * CHAR_WIDTH)))
    return "\n".join(textwrap.fill(line, chars, break_long_words=False) if line else line
                     for line in text.split("\n"))


def save_figure(fig, path: str | os.PathLike, dpi: int = 120) -> tuple[str, str]:
    """Write ``fig`` as PNG and SVG: ``path`` with its suffix replaced by ``.png`` and ``.svg``.

    Returns
    -------
    (png, svg) : str
        The two paths written.
    """
    stem = Path(path)
    if stem.suffix.lower() in {f".{f}" for f in FORMATS}:
        stem = stem.with_suffix("")
    out = []
    for fmt in FORMATS:
        target = stem.parent / f"{stem.name}.{fmt}"
        fig.savefig(target, format=fmt, dpi=dpi)
        out.append(str(target))
    return out[0], out[1]


def texts_outside(fig, tolerance: float = 1.0) -> list[str]:
    """Visible texts of ``fig`` that extend beyond the figure (cut off when saved).

    Draws the figure once (Agg renderer) and compares the window extent of every non-empty visible
    ``Text`` that is drawn (tick labels of ticks outside the view are not) with the figure's box.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    tolerance : float
        Pixels a text may overhang (anti-aliasing).

    Returns
    -------
    list of str
        One ``'text' at (x0, y0, x1, y1), figure (w, h)`` per text outside; empty when all fit.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.text import Text

    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    w, h = fig.bbox.width, fig.bbox.height
    skip = set()  # labels of ticks outside their axis' view: kept by matplotlib but never drawn
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                loc = tick.get_loc()
                if loc is None or not lo - 1e-9 * abs(hi - lo) <= loc <= hi + 1e-9 * abs(hi - lo):
                    skip.update((id(tick.label1), id(tick.label2)))
    bad = []
    for text in fig.findobj(Text):
        if id(text) in skip or not text.get_visible() or not text.get_text().strip():
            continue
        box = text.get_window_extent(renderer)
        if box.x0 < -tolerance or box.y0 < -tolerance or box.x1 > w + tolerance or box.y1 > h + tolerance:
            bad.append(f"{text.get_text()!r} at ({box.x0:.0f}, {box.y0:.0f}, {box.x1:.0f}, {box.y1:.0f}), "
                       f"figure ({w:.0f}, {h:.0f})")
    return bad
