"""Inputs on object storage (``s3://bucket/city/``, any fsspec URL): copied to local disk to be read.

meshsom's readers read local files (GDAL, trimesh, openNURBS, pymeshlab and IfcOpenShell take paths; the range
readers seek), so an input named by a URL is copied ("mirrored") before it is read:

- the planner copies every file under the URL (a folder: every object under its prefix; a file, with the files
  beside it that share its stem, a shapefile's sidecars, and ``labels.csv``; a glob) to its mirror folder, at
  ``<mirror>/<protocol>/<bucket>/<key>`` (:func:`mirror_inputs`), and plans from those copies as from local files
  (ids, kinds, ranges, splits); a file it never opens (a mesh, a CAD model: :data:`UNOPENED_SUFFIXES`) is a
  placeholder there, its size and no bytes; of a large plain CityGML file (:func:`heads_from`) it copies the head
  only, which says its kind, and finds its ranges by streaming it from its URL (:func:`open_bytes`); of a large
  GeoParquet file (:func:`columns_from`) the footer, the first row groups and the id columns;
- each read task is given the files it needs with their URLs (:func:`companions`: the file, the files sharing its
  stem, ``labels.csv`` beside it, and the whole folder of a glTF, KML, 3D Tiles tileset or File Geodatabase);
  a worker that lacks them (another machine; a placeholder) copies them to the same path of its own disk first
  (:func:`fetch`), once per machine: a lock file keeps two tasks from copying one file twice, and a file is copied
  whole, to a temporary name, then renamed; a task reading a range of a large file copies only its reader's bytes
  (:attr:`Copy.spans`) into a sparse file;
- the records' sources and the rejections' reasons name the URL, never the copy.

Nothing here imports Dask: the pipeline (:mod:`pipelines.corpus`) decides where the mirror is and removes it
when a run is done.
"""

from __future__ import annotations

import bisect
import fcntl
import glob as globbing
import json
import os
import shutil
import uuid
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath

from meshsom.errors import InputFileError

#: Folder names under which every file is needed to read any file of the folder: a File Geodatabase is one input.
WHOLE_FOLDER_SUFFIXES = (".gdb",)
#: Files whose folder (and its sub-folders) is needed to read them: a glTF's buffers and images, a KML's models, a
#: tileset's content.
WHOLE_FOLDER_NAMES = (".gltf", ".kml", "tileset.json")
#: Beside a file copied in part (:attr:`Copy.spans`): the byte spans copied so far (JSON). A file with one is not whole.
SPANS_SUFFIX = ".spans"
#: Files the planner never opens (their kind is their name's; only a read task reads them: meshes, CAD models, a
#: glTF's buffers and textures): it copies them as placeholders (a sparse file of their size, no bytes copied, listed
#: as such), and each read task copies its own (:func:`copy_all`). Every other file is copied: footprint files and
#: CityJSON, CityGML, zip and gzip files, which the planner reads to plan ranges, splits and parts.
UNOPENED_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".dae", ".b3dm", ".i3dm", ".cmpt", ".pnts",
                     ".3dm", ".dxf", ".ifc", ".ifczip", ".fbx", ".3ds", ".slpk", ".bin", ".mtl", ".png", ".jpg",
                     ".jpeg", ".webp", ".ktx2", ".tif", ".tiff",
                     ".osm", ".osm.pbf", ".osm.bz2", ".osm.gz")  # OpenStreetMap: its ranges planned by its size alone
#: CityJSON and CityJSONSeq files by name (never footprints, which the planner reads to pair parts): placeholders
#: too where they are too small to split or cut into ranges (:func:`unopened_below`); a 3D BAG's or a state's tiles.
SMALL_CITYJSON_SUFFIXES = (".city.json", ".cityjson", ".city.jsonl")
#: Files the planner reads the head of only, where they are large (:func:`heads_from`): CityGML, whose kind its head's
#: namespaces say and whose ranges the planner finds by streaming it from its URL (:func:`open_bytes`). Another file of
#: these names (INSPIRE's GML footprints, which GDAL reads whole) is copied whole once its kind is known.
HEAD_SUFFIXES = (".gml", ".xml")
#: The bytes of such a file's head copied by the planner (at least what :func:`meshsom.io.input_kind` looks at).
HEAD_BYTES = 1 << 16
#: Files the planner copies per call of the filesystem (:func:`copy_all`).
COPY_BATCH = 64
#: A file beside the meshes of its folder that names their labels (:func:`meshsom.io._labels_beside`).
LABELS_NAME = "labels.csv"


@dataclass(frozen=True)
class Copy:
    """A file of an input on object storage and where it is copied to.

    Attributes
    ----------
    url : str
    local : str
        Its path in the mirror folder.
    size : int
        Its size in bytes, as listed (a copy of another size is copied again).
    spans : list of [start, stop] or None
        The only bytes needed (a read task of a range of a large file: the file's head and tail and its range's
        bytes): copied into a sparse file of the file's size, the spans copied so far listed beside it
        (:data:`SPANS_SUFFIX`); None: the whole file.
    """

    url: str
    local: str
    size: int
    spans: list | None = None


def is_url(path) -> bool:
    """Whether an input is named by a URL (``s3://...``); ``file://`` is a local path."""
    s = os.fspath(path)
    return "://" in s and not s.startswith("file://")


def filesystem(url: str):
    """``(fsspec filesystem, path inside it)`` of a URL, with the backend missing named (:func:`meshsom.store.filesystem`)."""
    from meshsom.errors import StoreError
    from meshsom.store import filesystem as store_filesystem

    try:
        return store_filesystem(url)
    except StoreError as err:
        raise InputFileError(url, str(err).split(": ", 1)[-1]) from None


#: Bytes asked of object storage at a time where a file is streamed (:func:`open_bytes`).
STREAM_BLOCK_BYTES = 1 << 24


def open_bytes(source, block_size: int = STREAM_BLOCK_BYTES):
    """A binary file object of a local file, or of a file named by a URL streamed from where it lies (fsspec, in
    blocks of ``block_size`` bytes at least: a scan over a large file on object storage that copies nothing; a
    smaller block for a file read at a few places, such as a Parquet file's footer)."""
    if is_url(source):
        fs, path = filesystem(os.fspath(source))
        return fs.open(path, "rb", block_size=block_size, cache_type="readahead")
    return open(source, "rb")


def mirror_path(url: str, root: Path) -> Path:
    """Where a URL's file is copied to in the mirror folder ``root``: ``<root>/<protocol>/<path>``."""
    protocol, rest = url.split("://", 1)
    parts = [p for p in PurePosixPath(rest).parts if p not in ("", "/", ".", "..")]
    return Path(root, protocol, *parts)


def remote_files(url: str) -> tuple[list[str], list[Copy]]:
    """The files of an input URL, not yet copied: every file under a folder's prefix; or a file, or the files a glob
    matches, each with the files beside it that share its stem (a shapefile's sidecars) and ``labels.csv``.

    Returns
    -------
    inputs : list of str
        What is read: the folder's URL, the file's, or each file the glob matches. Empty where nothing is there.
    copies : list of Copy
        Every file to copy, ``local`` relative (:func:`mirror_path` gives it a root).

    Raises
    ------
    InputFileError
        The URL's protocol has no backend installed, or the storage cannot be listed (credentials, endpoint).
    """
    fs, path = filesystem(url)
    try:
        if globbing.has_magic(path):
            matched = [p for p in fs.glob(path) if fs.isfile(p)]
        elif fs.isdir(path):
            found = fs.find(path, detail=True)
            return [url], [_copy(fs, p, i) for p, i in sorted(found.items()) if i.get("type", "file") != "directory"]
        elif fs.isfile(path):
            matched = [path]
        else:
            return [], []
        found = {}
        for parent in sorted({p.rsplit("/", 1)[0] for p in matched}):  # each folder listed once
            stems = {p.rsplit("/", 1)[-1].split(".", 1)[0] for p in matched if p.rsplit("/", 1)[0] == parent}
            for p, info in fs.find(parent, maxdepth=1, detail=True).items():
                name = p.rsplit("/", 1)[-1]
                if name.split(".", 1)[0] in stems or name == LABELS_NAME:
                    found[p] = info
    except (OSError, PermissionError) as err:
        raise InputFileError(url, f"cannot be listed ({type(err).__name__}: {err})") from None
    return ([fs.unstrip_protocol(p) for p in sorted(matched)],
            [_copy(fs, p, i) for p, i in sorted(found.items()) if i.get("type", "file") != "directory"])


def _copy(fs, path: str, info: dict) -> Copy:
    """The :class:`Copy` of a file of a listing (its size asked for where the listing has none: a web server's)."""
    url = fs.unstrip_protocol(path)
    size = info.get("size")
    if size is None:
        size = fs.info(path).get("size")
    return Copy(url, str(mirror_path(url, Path("."))), int(size or 0))


def fetch(copies) -> None:
    """Copy the files of ``copies`` (:class:`Copy`, or their fields as a dict) that are not on this machine at their
    size; the others are left as they are. A lock file beside each keeps two processes of one machine from copying
    it at once; a whole copy is written under a temporary name and renamed, so a file at its path is whole unless a
    spans file lies beside it: a copy of :attr:`Copy.spans` only writes those bytes into a sparse file, and lists
    them beside it, so that ranges of one large file read on one machine each copy theirs.

    Raises
    ------
    InputFileError
        A file cannot be copied (gone, no permission), naming its URL.
    """
    for c in copies:
        c = Copy(**c) if isinstance(c, dict) else c
        target = Path(c.local)
        if _whole(target, c.size):
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        with open(f"{target}.lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if _whole(target, c.size):
                continue
            fs, path = filesystem(c.url)
            try:
                if c.spans is not None:
                    _copy_spans(fs, path, target, c)
                    continue
                part = target.with_name(f"{target.name}.part-{uuid.uuid4().hex[:8]}")
                try:
                    fs.get_file(path, str(part))
                    os.replace(part, target)
                    Path(f"{target}{SPANS_SUFFIX}").unlink(missing_ok=True)
                finally:
                    part.unlink(missing_ok=True)
            except (OSError, PermissionError) as err:
                raise InputFileError(c.url, f"cannot be copied to {target} ({type(err).__name__}: {err})") from None


def _copy_spans(fs, path: str, target: Path, c: Copy) -> None:
    """The bytes of ``c.spans`` not yet in ``target`` copied into it (a sparse file of ``c.size`` bytes, made where
    there is none), and listed in its spans file (written after the bytes, so that it lists only what is there)."""
    listed = Path(f"{target}{SPANS_SUFFIX}")
    have = [tuple(s) for s in json.loads(listed.read_text())] if listed.exists() and target.exists() else []
    if not have:
        with open(target, "wb") as out:  # holes read as zeros and take no disk
            out.truncate(c.size)
        listed.write_text("[]")
    wanted = [(max(0, int(a)), min(c.size, int(b))) for a, b in c.spans if min(c.size, int(b)) > max(0, int(a))]
    missing = [(a, b) for a, b in wanted if not any(x <= a and b <= y for x, y in have)]
    with open(target, "r+b") as out:
        for a, b in missing:
            out.seek(a)
            out.write(fs.cat_file(path, start=a, end=b))
    if missing:
        temporary = listed.with_name(f"{listed.name}.{uuid.uuid4().hex[:8]}")
        temporary.write_text(json.dumps(sorted(have + missing)))
        os.replace(temporary, listed)


def copy_all(copies: list[Copy], progress=None, unopened=None, heads=None) -> None:
    """Copy the files of ``copies`` not on this machine at their size, :data:`COPY_BATCH` at a time, each batch in one
    call of the filesystem (s3fs copies a batch's files concurrently): the planner's copy of a whole city, with
    nothing else copying into the mirror folder yet; a file the planner never opens (``unopened(copy)``; default: by
    its name, :data:`UNOPENED_SUFFIXES`) is a placeholder, copied by the read task that reads it; of a file whose head
    only the planner reads (``heads(copy)``, :func:`heads_from`) only its first :data:`HEAD_BYTES` are copied, into a
    placeholder. ``progress(done, total)`` after each batch.

    Raises
    ------
    InputFileError
        A file cannot be copied, naming its URL (what was copied before stays).
    """
    unopened = unopened or (lambda c: _unopened(c.local))
    missing = [c for c in copies if not _whole(Path(c.local), c.size)]
    for c in [c for c in missing if unopened(c)]:  # the workers copy these: a placeholder here
        if not Path(f"{c.local}{SPANS_SUFFIX}").exists():
            Path(c.local).parent.mkdir(parents=True, exist_ok=True)
            with open(c.local, "wb") as out:
                out.truncate(c.size)
            Path(f"{c.local}{SPANS_SUFFIX}").write_text("[]")
    missing = [c for c in missing if not unopened(c)]
    for c in [c for c in missing if heads is not None and heads(c)]:  # its head: its kind; its ranges are streamed
        Path(c.local).parent.mkdir(parents=True, exist_ok=True)
        fs, path = filesystem(c.url)
        try:
            _copy_spans(fs, path, Path(c.local), replace(c, spans=[[0, min(HEAD_BYTES, c.size)]]))
        except (OSError, PermissionError) as err:
            raise InputFileError(c.url, f"cannot be copied ({type(err).__name__}: {err})") from None
    missing = [c for c in missing if heads is None or not heads(c)]
    for start in range(0, len(missing), COPY_BATCH):
        batch = missing[start:start + COPY_BATCH]
        fs, _ = filesystem(batch[0].url)
        parts = [Path(c.local).with_name(f"{Path(c.local).name}.part-{uuid.uuid4().hex[:8]}") for c in batch]
        for part in parts:
            part.parent.mkdir(parents=True, exist_ok=True)
        try:
            fs.get([filesystem(c.url)[1] for c in batch], [str(part) for part in parts])
            for c, part in zip(batch, parts):
                os.replace(part, c.local)
                Path(f"{c.local}{SPANS_SUFFIX}").unlink(missing_ok=True)
        except (OSError, PermissionError) as err:
            fetch(batch)  # one at a time: the error names the file
            raise InputFileError(batch[0].url, f"cannot be copied ({type(err).__name__}: {err})") from None
        finally:
            for part in parts:
                part.unlink(missing_ok=True)
        if progress is not None:
            progress(start + len(batch), len(missing))


def _unopened(local: str) -> bool:
    """Whether the planner never opens a file of this name (:data:`UNOPENED_SUFFIXES`)."""
    return local.lower().endswith(UNOPENED_SUFFIXES)


def unopened_below(limit: int):
    """The planner's test of a file it never opens (:func:`copy_all`): by its name (:data:`UNOPENED_SUFFIXES`), or a
    CityJSON or CityJSONSeq file by name (:data:`SMALL_CITYJSON_SUFFIXES`, never a footprint file) under ``limit``
    bytes, which the planner neither splits nor cuts into ranges (twice ``dask.read_bytes``)."""
    def test(c: Copy) -> bool:
        return _unopened(c.local) or (c.local.lower().endswith(SMALL_CITYJSON_SUFFIXES) and c.size < limit)
    return test


def heads_from(limit: int):
    """The planner's test of a file whose head only it reads (:func:`copy_all`): one named as CityGML can be
    (:data:`HEAD_SUFFIXES`, not gzipped) of ``limit`` bytes or more (twice ``dask.read_bytes``: cut into ranges found
    by streaming it, :func:`open_bytes`); smaller ones are copied whole, many at a time."""
    def test(c: Copy) -> bool:
        return c.local.lower().endswith(HEAD_SUFFIXES) and c.size >= limit
    return test


def columns_from(limit: int):
    """The planner's test of a file of which it reads some columns only, where it is large: a GeoParquet file
    (:data:`meshsom.gis.PARQUET_SUFFIXES`) of ``limit`` bytes or more (twice ``dask.read_bytes``). It is a placeholder
    at first (give it to :func:`copy_all` as ``unopened``); the planner then copies the spans it reads
    (:func:`meshsom.gis.parquet_planned_spans`: the footer, the first row groups, the id columns), and each read task
    its own (its rows' row groups, :func:`meshsom.gis.parquet_spans`). Smaller ones are copied whole, many at a
    time."""
    from meshsom.gis import PARQUET_SUFFIXES

    def test(c: Copy) -> bool:
        return c.local.lower().endswith(PARQUET_SUFFIXES) and c.size >= limit
    return test


def is_partial(path) -> bool:
    """Whether a file of the mirror holds only some of its bytes (a placeholder, a head, a range's spans)."""
    return Path(f"{os.fspath(path)}{SPANS_SUFFIX}").exists()


def _whole(path: Path, size: int) -> bool:
    """Whether ``path`` is a whole copy: of its size, without a spans file beside it."""
    try:
        return path.stat().st_size == size and not is_partial(path)
    except OSError:
        return False


@dataclass
class Mirrored:
    """Inputs with those named by URLs copied (:func:`mirror_inputs`).

    Attributes
    ----------
    paths : list of str
        The inputs, each URL replaced by its copy (a folder, a file, or each file a glob matches).
    urls : dict
        ``{copy: URL}`` of each input URL (of a glob's, each file): a prefix of its copies' paths and that of their
        URLs (:func:`as_url`).
    copies : Copies
        Every file copied, by its local path.
    missing : list of (URL, reason)
        URLs under which there is nothing, or that cannot be listed.
    """

    paths: list
    urls: dict
    copies: dict
    missing: list


def mirror_inputs(inputs, root: Path, progress=None, unopened=None, heads=None) -> Mirrored:
    """Copy the inputs named by URLs into the mirror folder ``root`` (:func:`copy_all`: what is there at its size
    already is kept, ``unopened`` files are placeholders, of ``heads`` files only their heads are copied;
    ``progress(done, total)`` as it goes); local inputs stay as they are."""
    paths, urls, copies, missing = [], {}, Copies(), []
    for item in inputs:
        if not is_url(item):
            paths.append(os.fspath(item))
            continue
        url = os.fspath(item).rstrip("/")
        try:
            matched, found = remote_files(url)
        except InputFileError as err:
            missing.append((url, err.problem))
            continue
        if not matched:
            missing.append((url, "no such file or folder (nothing under this URL)"))
            continue
        placed = [Copy(c.url, str(Path(root, c.local)), c.size) for c in found]
        try:
            copy_all(placed, progress, unopened, heads)
        except InputFileError as err:
            missing.append((url, f"{err.source}: {err.problem}"))
            continue
        copies.update({c.local: c for c in placed})
        for m in matched:
            paths.append(str(mirror_path(m, root)))
            urls[paths[-1]] = m
    return Mirrored(paths, urls, copies, missing)


def url_rename(path, urls: dict) -> tuple[str, str] | None:
    """``(copy, URL)`` of the input URL whose copy ``path`` is or lies in (:class:`Mirrored`), else None."""
    text = os.fspath(path)
    for local in sorted(urls, key=len, reverse=True):
        if text == local or text.startswith(local.rstrip("/") + "/"):
            return local, urls[local]
    return None


def as_url(text: str, urls: dict) -> str:
    """``text`` (a path, a reason) with a copy's path at its start named by its URL."""
    found = url_rename(text.split(" ", 1)[0], urls) if text else None
    return text if found is None else found[1] + text[len(found[0]):]


class Copies(dict):
    """Copied files by their local path (``{local: Copy}``), indexed by folder once, so that the files of each of a
    city's thousands of inputs are found without a pass over all of them (:func:`companions`)."""

    def _index(self):
        if getattr(self, "_size", None) != len(self):
            self._folders: dict[str, list[Copy]] = {}
            for local, c in self.items():
                self._folders.setdefault(os.path.dirname(local), []).append(c)
            self._sorted = sorted(self)
            self._size = len(self)

    def in_folder(self, folder) -> list[Copy]:
        """The copies directly in ``folder``."""
        self._index()
        return self._folders.get(os.fspath(folder), [])

    def under(self, folder) -> list[Copy]:
        """The copies in ``folder`` and its sub-folders."""
        self._index()
        prefix = os.fspath(folder).rstrip("/") + "/"
        start = bisect.bisect_left(self._sorted, prefix)
        stop = bisect.bisect_left(self._sorted, prefix[:-1] + chr(ord("/") + 1))
        return [self[k] for k in self._sorted[start:stop]]


def companions(path: Path, copies: Copies) -> list[Copy]:
    """The copied files needed to read the mirrored input ``path`` (a file or a File Geodatabase folder): itself,
    the files beside it that share its stem (a shapefile's sidecars, an OBJ's material library), ``labels.csv``
    beside it, and every file of its folder and sub-folders for a glTF, KML, tileset or File Geodatabase."""
    path = Path(path)
    name = path.name.lower()
    if path.is_dir() or name.endswith(WHOLE_FOLDER_SUFFIXES):
        return copies.under(path)
    if name.endswith(WHOLE_FOLDER_NAMES) or name.removesuffix(".gz").endswith(WHOLE_FOLDER_NAMES):
        return copies.under(path.parent)
    stem = path.name.split(".", 1)[0]
    return [c for c in copies.in_folder(path.parent) if c.local == str(path) or
            os.path.basename(c.local).startswith(stem + ".") or os.path.basename(c.local) == LABELS_NAME]


def remove_mirror(root: Path) -> None:
    """Delete a mirror folder (nothing there is fine)."""
    shutil.rmtree(root, ignore_errors=True)
