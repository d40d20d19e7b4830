"""Mesh thumbnails and the domain-map figure (the paper's Figure 9).

A thumbnail is a small shaded view of one mesh on a transparent background, drawn with a
matplotlib ``Figure`` on an Agg canvas (no pyplot: a notebook's backend is left alone).
Thumbnails of one figure share one scale (:func:`render_thumbnails`), so a large building looks
larger than a small one. :func:`domain_map_figure` draws the domain map's grid with every mesh's
thumbnail in the cell of its unit and its short id under it (several meshes on one unit share the
cell as a small mosaic), optionally framed in the colour of its label, and writes PNG and SVG.
"""

from __future__ import annotations

import os

import numpy as np

from meshsom.figures import fit_text, new_figure, save_figure
from meshsom.metrics import TOPOLOGIES

__all__ = ["domain_map_figure", "draw_domain_map", "face_shading", "render_thumbnail", "render_thumbnails",
           "short_ids", "view_half"]

#: Direction of the light (towards the light), in world coordinates, before normalisation.
LIGHT = (0.8, -0.3, 0.6)
#: Shading: ``AMBIENT + DIFFUSE * |n . l|`` times the base colour.
AMBIENT, DIFFUSE = 0.25, 0.75
BASE_COLOUR = (0.80, 0.78, 0.72)
#: Characters of a mesh id kept at most on a thumbnail (after the prefix every id shares).
ID_CHARS = 10
#: Font size of the ids under the thumbnails, in points, for a one-mesh cell.
ID_FONT = 5.5


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


def view_half(vertices) -> float:
    """Half the side of the cube that holds a mesh in every view: half its bounding-box diagonal.

    Parameters
    ----------
    vertices : (V, 3) float64

    Returns
    -------
    float
        > 0.
    """
    v = np.asarray(vertices, np.float64)
    return max(float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) / 2.0, 1e-12)


#: Zoom of the 3-D axes: the cube of half-side :func:`view_half` around the mesh, seen orthographically,
#: fills the image without cutting the mesh in any view.
ZOOM = 1.6


def render_thumbnail(vertices, faces, size: int = 64, elev: float = 25.0, azim: float = -60.0,
                     half: float | None = None, colours=None, edges=None) -> np.ndarray:
    """A small shaded view of a mesh, with equal axes, on a transparent background.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    size : int
        Width and height in pixels.
    elev, azim : float
        View angles in degrees (matplotlib's ``view_init``).
    half : float or None
        Half the side of the view cube, in mesh units, centred on the mesh's bounding box; the same
        value for several meshes draws them at one scale. None: :func:`view_half` of this mesh
        (it fills the image). Must be >= this mesh's own :func:`view_half` or the mesh is cut.
    colours : (F, 3) float or None
        Base colour of every face in [0, 1] (shaded like the default); None: one neutral colour.
    edges : colour or None
        Colour of the face edges; None: edges in the face colours (no visible lines).

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
    base = np.broadcast_to(np.asarray(BASE_COLOUR if colours is None else colours, np.float64), (len(faces), 3))
    own = view_half(vertices)
    half = own if half is None else float(half)
    if half < own * (1 - 1e-9):
        raise ValueError(f"half must be >= the mesh's own view_half {own:.6g} (else it is cut), received {half:.6g}")
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = (lo + hi) / 2.0
    shade = face_shading(vertices, faces)
    face_rgba = np.column_stack([np.clip(shade[:, None] * base, 0.0, 1.0), np.ones(len(faces))])
    fig = new_figure((1.0, 1.0), layout=None)
    fig.patch.set_alpha(0.0)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0), projection="3d")
    ax.set_facecolor((0.0, 0.0, 0.0, 0.0))
    ax.set_proj_type("ortho")
    ax.add_collection3d(Poly3DCollection(vertices[faces], facecolors=face_rgba,
                                         edgecolors=face_rgba if edges is None else edges,
                                         linewidths=0.3 if edges is None else 0.4))
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_box_aspect((1.0, 1.0, 1.0), zoom=ZOOM)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    fig.set_dpi(size)
    fig.canvas.draw()
    image = np.array(fig.canvas.buffer_rgba(), dtype=np.uint8)
    if image.shape[:2] != (size, size):  # guard against rounding of the figure size
        pad = np.zeros((size, size, 4), np.uint8)
        h, w = min(size, image.shape[0]), min(size, image.shape[1])
        pad[:h, :w] = image[:h, :w]
        image = pad
    return image


def render_thumbnails(meshes, size: int = 64, **kwargs) -> tuple[list[np.ndarray], float]:
    """Thumbnails of several meshes at one common scale (the largest mesh fills its image).

    Parameters
    ----------
    meshes : sequence of (vertices (V, 3) float64, faces (F, 3) int64)
    size : int
        Pixels per side.
    **kwargs
        Passed to :func:`render_thumbnail` (``elev``, ``azim``).

    Returns
    -------
    images : list of (size, size, 4) uint8
    half : float
        The common half-side of the view cube, in mesh units: an image spans ``2 * half``.
    """
    meshes = list(meshes)
    if not meshes:
        return [], 1.0
    half = max(view_half(v) for v, _ in meshes)
    return [render_thumbnail(v, f, size=size, half=half, **kwargs) for v, f in meshes], half


def short_ids(ids, chars: int = ID_CHARS) -> list[str]:
    """Short labels for mesh ids: the prefix every id shares removed, the rest cut to ``chars``.

    ``zurich.city.json#UUID_583c776f-5b0c-...`` becomes ``583c776f-5`` when every id starts with
    ``zurich.city.json#UUID_``. Where cutting makes two labels equal, the store index is used for
    all (``#0``, ``#1``, ...).

    Parameters
    ----------
    ids : (n,) str
    chars : int

    Returns
    -------
    list of str, length n
    """
    ids = [str(i) for i in ids]
    if not ids:
        return []
    common = os.path.commonprefix(ids) if len(ids) > 1 else ""
    short = [(i[len(common):] or i)[:chars] for i in ids]
    if len(set(short)) < len(set(ids)):
        return [f"#{k}" for k in range(len(ids))]
    return short


def _mosaic(n: int) -> int:
    """Side of the smallest square mosaic holding ``n`` thumbnails."""
    return int(np.ceil(np.sqrt(n)))


def draw_domain_map(units, thumbnails, rows: int, cols: int, title: str = "Domain map", labels=None,
                    topology: str = "toroidal", ids=None, span: float | None = None, cell_inches: float = 1.0):
    """The domain map as a figure: every mesh's thumbnail at its unit, its short id under it.

    Parameters
    ----------
    units : (n,) int
        Unit of every mesh on the domain map (row-major, ``0..rows*cols-1``).
    thumbnails : sequence of (s, s, 4) uint8, length n
        From :func:`render_thumbnails` (one scale) or :func:`render_thumbnail`.
    rows, cols : int
        Domain map size.
    title : str
        Wrapped to the figure's width; the map size, topology and mesh count are added.
    labels : (n,) any or None
        Family of every mesh: drawn as a coloured frame around its thumbnail, with a legend.
    topology : {"toroidal", "planar"}
        Named under the title: a toroidal map's opposite edges touch.
    ids : (n,) str or None
        Mesh ids; shortened by :func:`short_ids` and written under the thumbnails.
    span : float or None
        Mesh units one full-cell thumbnail spans (``2 * half`` of :func:`render_thumbnails`), for the
        caption; None: the thumbnails are not said to share a scale.
    cell_inches : float
        Size of one grid cell in the figure.

    Returns
    -------
    matplotlib.figure.Figure
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
    if ids is not None and len(ids) != n:
        raise ValueError(f"expected one id per mesh ({n}), received {len(ids)}")
    import matplotlib
    from matplotlib.patches import Patch, Rectangle

    legend_inches = 1.6 if labels is not None else 0.0
    width = max(cols * cell_inches + 0.6 + legend_inches, 5.0)
    fig = new_figure((width, rows * cell_inches + 1.9))
    ax = fig.add_subplot()
    ax.set_xlim(0, cols)
    ax.set_ylim(rows, 0)
    ax.set_aspect("equal")
    ax.set_xticks(np.arange(cols) + 0.5, [str(c) for c in range(cols)], fontsize=6)
    ax.set_yticks(np.arange(rows) + 0.5, [str(r) for r in range(rows)], fontsize=6)
    ax.tick_params(length=0)
    ax.set_xlabel("domain-map column", fontsize=8)
    ax.set_ylabel("domain-map row", fontsize=8)
    for x in range(cols + 1):
        ax.axvline(x, color="0.8", linewidth=0.5, zorder=0)
    for y in range(rows + 1):
        ax.axhline(y, color="0.8", linewidth=0.5, zorder=0)

    colour_of = {}
    if labels is not None:
        cmap = matplotlib.colormaps["tab10" if len(np.unique(labels)) <= 10 else "tab20"]
        colour_of = {lab: cmap(i % cmap.N) for i, lab in enumerate(np.unique(labels))}
    names = short_ids(ids) if ids is not None else None
    order = np.argsort(units, kind="stable")
    starts = np.flatnonzero(np.r_[True, units[order][1:] != units[order][:-1]]) if n else np.array([], int)
    for s, e in zip(starts, np.r_[starts[1:], n]):  # one group per occupied unit
        members = order[s:e]
        r, c = divmod(int(units[members[0]]), cols)
        side = _mosaic(len(members))
        step = 1.0 / side
        text_h = 0.2 * step if names is not None else 0.0
        for k, m in enumerate(members):
            i, j = divmod(k, side)
            x0, y0 = c + j * step, r + i * step
            pad = 0.04 * step
            img = step - text_h - pad  # the thumbnail is a square above its id
            xc = x0 + step / 2
            ax.imshow(thumbnails[m], extent=(xc - img / 2, xc + img / 2, y0 + pad + img, y0 + pad),
                      interpolation="bilinear", zorder=2)
            if names is not None:
                ax.text(xc, y0 + step - text_h / 2, names[m], ha="center", va="center", zorder=3,
                        fontsize=max(3.0, ID_FONT * cell_inches / side), clip_on=True)
            if labels is not None:
                ax.add_patch(Rectangle((x0 + pad / 2, y0 + pad / 2), step - pad, step - pad, fill=False,
                                       edgecolor=colour_of[labels[m]], linewidth=1.2, zorder=3))
    ax.set_xlim(0, cols)
    ax.set_ylim(rows, 0)
    note = "torus: opposite edges touch" if topology == "toroidal" else "planar"
    ax.set_title(fit_text(f"{title}\n{rows} x {cols} {note}; {n} meshes", width - 1.0, 11), fontsize=11)
    caption = []
    if span is not None:
        caption.append(f"All thumbnails at one scale: a thumbnail filling a cell spans {span:.3g} mesh units; "
                       "a cell shared by k meshes shows a mosaic of ceil(sqrt(k)) per side at that fraction "
                       "of the scale.")
    if names is not None:
        common = os.path.commonprefix([str(i) for i in ids]) if n > 1 and not names[0].startswith("#") else ""
        caption.append(f"Labels: mesh ids after their common prefix '{common}'." if common
                       else "Labels: mesh ids." if not names or not names[0].startswith("#")
                       else "Labels: mesh index in the store.")
    if caption:
        fig.supxlabel(fit_text(" ".join(caption), width - 0.4, 7.5), fontsize=7.5, ha="center")
    if labels is not None:
        handles = [Patch(facecolor="none", edgecolor=col, linewidth=1.5, label=str(lab))
                   for lab, col in colour_of.items()]
        fig.legend(handles=handles, loc="outside right upper", fontsize=8, frameon=False, title="label")
    return fig


def domain_map_figure(units, thumbnails, rows: int, cols: int, path: str | os.PathLike,
                      title: str = "Domain map", labels=None, topology: str = "toroidal",
                      cell_inches: float = 1.0, dpi: int = 120, ids=None, span: float | None = None) -> str:
    """Draw the domain map (:func:`draw_domain_map`) and write it as PNG and SVG.

    Parameters
    ----------
    units, thumbnails, rows, cols, title, labels, topology, cell_inches, ids, span
        See :func:`draw_domain_map`.
    path : path
        The PNG; the SVG is written beside it with the same stem.
    dpi : int

    Returns
    -------
    str
        The PNG's path (the SVG is ``Path(png).with_suffix(".svg")``).
    """
    fig = draw_domain_map(units, thumbnails, rows, cols, title, labels, topology, ids, span, cell_inches)
    return save_figure(fig, path, dpi)[0]
