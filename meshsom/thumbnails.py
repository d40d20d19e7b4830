"""Mesh thumbnails and the domain-map figure (the paper's Figure 9).

Rendering uses matplotlib's Agg backend, imported lazily. A thumbnail is a small shaded
view of one mesh on a transparent background; :func:`domain_map_figure` draws the domain
map's grid with every mesh's thumbnail in the cell of its unit (several meshes on one unit
share the cell as a small mosaic), optionally framed in the colour of its label.
"""

from __future__ import annotations

import os

import numpy as np

from meshsom.metrics import TOPOLOGIES

#: Direction of the light (towards the light), in world coordinates, before normalisation.
LIGHT = (0.8, -0.3, 0.6)
#: Shading: ``AMBIENT + DIFFUSE * |n . l|`` times the base colour.
AMBIENT, DIFFUSE = 0.25, 0.75
BASE_COLOUR = (0.80, 0.78, 0.72)


def _pyplot():
    try:
        import matplotlib
    except ImportError:  # pragma: no cover - matplotlib is a dependency
        raise ImportError("rendering thumbnails needs matplotlib: pip install matplotlib") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def face_shading(vertices, faces, light=LIGHT) -> np.ndarray:
    """Lambert-like brightness of every face: ``AMBIENT + DIFFUSE * |n . l|``.

    The absolute value makes it independent of the faces' orientation.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64

    Returns
    -------
    (F,) float64
        In ``[AMBIENT, AMBIENT + DIFFUSE]``.
    """
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    n = n / np.where(norm > 0, norm, 1.0)[:, None]
    light = np.asarray(light, np.float64)
    light = light / np.linalg.norm(light)
    return AMBIENT + DIFFUSE * np.abs(n @ light)


def render_thumbnail(vertices, faces, size: int = 64, elev: float = 25.0, azim: float = -60.0) -> np.ndarray:
    """A small shaded view of a mesh, with equal axes, on a transparent background.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    size : int
        Width and height in pixels.
    elev, azim : float
        View angles in degrees (matplotlib's ``view_init``).

    Returns
    -------
    (size, size, 4) uint8
        RGBA; alpha 0 where no face is drawn.
    """
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise ValueError(f"vertices must be a non-empty (V, 3) array, received shape {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces must be a non-empty (F, 3) array, received shape {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise TypeError(f"faces must hold integers, received dtype {faces.dtype}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"faces reference vertices {faces.min()}..{faces.max()}, mesh has {len(vertices)} vertices")
    if size < 8:
        raise ValueError(f"size must be >= 8 pixels, received {size}")
    plt = _pyplot()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = (lo + hi) / 2.0
    half = max(float((hi - lo).max()) / 2.0, 1e-12)
    shade = face_shading(vertices, faces)
    colours = np.column_stack([shade[:, None] * np.asarray(BASE_COLOUR), np.ones(len(faces))])
    fig = plt.figure(figsize=(1.0, 1.0), dpi=size)
    fig.patch.set_alpha(0.0)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0), projection="3d")
    ax.set_facecolor((0.0, 0.0, 0.0, 0.0))
    ax.add_collection3d(Poly3DCollection(vertices[faces], facecolors=colours, edgecolors=colours,
                                         linewidths=0.3))
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_box_aspect((1.0, 1.0, 1.0), zoom=1.35)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    fig.canvas.draw()
    image = np.array(fig.canvas.buffer_rgba(), dtype=np.uint8)
    plt.close(fig)
    if image.shape[:2] != (size, size):  # guard against rounding of the figure size
        pad = np.zeros((size, size, 4), np.uint8)
        h, w = min(size, image.shape[0]), min(size, image.shape[1])
        pad[:h, :w] = image[:h, :w]
        image = pad
    return image


def _mosaic(n: int) -> int:
    """Side of the smallest square mosaic holding ``n`` thumbnails."""
    return int(np.ceil(np.sqrt(n)))


def domain_map_figure(units, thumbnails, rows: int, cols: int, path: str | os.PathLike,
                      title: str = "Domain map", labels=None, topology: str = "toroidal",
                      cell_inches: float = 0.8, dpi: int = 120) -> str:
    """Draw the domain map with every mesh's thumbnail at its unit and save a PNG.

    Parameters
    ----------
    units : (n,) int
        Unit of every mesh on the domain map (row-major, ``0..rows*cols-1``).
    thumbnails : sequence of (s, s, 4) uint8, length n
        From :func:`render_thumbnail`.
    rows, cols : int
        Domain map size.
    path : path
        PNG to write.
    title : str
    labels : (n,) any or None
        Family of every mesh: drawn as a coloured frame around its thumbnail, with a legend.
    topology : {"toroidal", "planar"}
        Only named in the title: a toroidal map's opposite edges touch.
    cell_inches : float
        Size of one grid cell in the figure.
    dpi : int

    Returns
    -------
    str
        The path written.
    """
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {', '.join(TOPOLOGIES)}; received {topology!r}")
    units = np.asarray(units)
    if units.ndim != 1 or (units.size and not np.issubdtype(units.dtype, np.integer)):
        raise ValueError(f"units must be a 1-D integer array, received shape {units.shape}, dtype {units.dtype}")
    units = units.astype(np.int64)
    n = len(units)
    if len(thumbnails) != n:
        raise ValueError(f"expected one thumbnail per mesh ({n}), received {len(thumbnails)}")
    if n and (units.min() < 0 or units.max() >= rows * cols):
        raise ValueError(f"units must lie in 0..{rows * cols - 1} for a {rows} x {cols} map, "
                         f"received {units.min()}..{units.max()}")
    if labels is not None:
        labels = np.asarray(labels)
        if labels.shape != (n,):
            raise ValueError(f"labels must have shape ({n},) like units, received {labels.shape}")
    plt = _pyplot()
    from matplotlib.patches import Patch, Rectangle

    fig, ax = plt.subplots(figsize=(cols * cell_inches + (2.2 if labels is not None else 0.4),
                                    rows * cell_inches + 0.8))
    ax.set_xlim(0, cols)
    ax.set_ylim(rows, 0)
    ax.set_aspect("equal")
    ax.set_xticks(np.arange(cols) + 0.5, [str(c) for c in range(cols)], fontsize=6)
    ax.set_yticks(np.arange(rows) + 0.5, [str(r) for r in range(rows)], fontsize=6)
    ax.tick_params(length=0)
    for x in range(cols + 1):
        ax.axvline(x, color="0.8", linewidth=0.5, zorder=0)
    for y in range(rows + 1):
        ax.axhline(y, color="0.8", linewidth=0.5, zorder=0)

    colour_of = {}
    if labels is not None:
        cmap = plt.get_cmap("tab10" if len(np.unique(labels)) <= 10 else "tab20")
        colour_of = {lab: cmap(i % cmap.N) for i, lab in enumerate(np.unique(labels))}
    order = np.argsort(units, kind="stable")
    starts = np.flatnonzero(np.r_[True, units[order][1:] != units[order][:-1]]) if n else np.array([], int)
    for s, e in zip(starts, np.r_[starts[1:], n]):  # one group per occupied unit
        members = order[s:e]
        r, c = divmod(int(units[members[0]]), cols)
        side = _mosaic(len(members))
        step = 1.0 / side
        for k, m in enumerate(members):
            i, j = divmod(k, side)
            x0, y0 = c + j * step, r + i * step
            pad = 0.06 * step
            ax.imshow(thumbnails[m], extent=(x0 + pad, x0 + step - pad, y0 + step - pad, y0 + pad),
                      interpolation="bilinear", zorder=2)
            if labels is not None:
                ax.add_patch(Rectangle((x0 + pad / 2, y0 + pad / 2), step - pad, step - pad, fill=False,
                                       edgecolor=colour_of[labels[m]], linewidth=1.2, zorder=3))
    ax.set_xlim(0, cols)
    ax.set_ylim(rows, 0)
    note = "torus: opposite edges touch" if topology == "toroidal" else "planar"
    ax.set_title(f"{title} ({rows} x {cols}, {note}; {n} meshes)")
    if labels is not None:
        handles = [Patch(facecolor="none", edgecolor=col, linewidth=1.5, label=str(lab))
                   for lab, col in colour_of.items()]
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return str(path)
