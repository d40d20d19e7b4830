"""Reading zip archives of city models: the form most downloads take (German states' LoD2
CityGML tiles, New York's and PLATEAU's city models, zipped shapefiles and tilesets).

A ``.zip`` is extracted into a temporary folder, read as a folder is
(:func:`meshsom.io.expand_inputs`: a shapefile with its sidecars, a File Geodatabase folder, a
tileset with its tiles), and removed. Ids are ``name/<member path>#<object>``; every item's
``source`` is ``archive.zip!/<member path>``. Guards:

- the members may expand to at most :attr:`meshsom.io.ReaderOptions.max_bytes` in all, each to at
  most :attr:`meshsom.io.ReaderOptions.max_expansion` times its compressed size (plus
  :data:`meshsom.io.GZIP_FREE_BYTES`): a zip bomb is a rejection before anything is extracted, and
  extraction stops at each member's declared size;
- member names are extracted beneath the temporary folder only (``..`` and absolute names are
  made relative, as :meth:`zipfile.ZipFile.extract` does), links are not created;
- a zip inside the zip is listed, not opened.
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Iterator

from meshsom.errors import InputFileError

ZIP_SUFFIX = ".zip"
#: Bytes copied at a time while extracting.
COPY_CHUNK_BYTES = 1 << 20


def _check_sizes(path: Path, members: list[zipfile.ZipInfo], options) -> None:
    from meshsom.io import GZIP_FREE_BYTES

    total = sum(m.file_size for m in members)
    if total > options.max_bytes:
        raise InputFileError(str(path), f"expands to {total:,} bytes, more than max_bytes ({options.max_bytes:,})")
    for m in members:
        if m.file_size > options.max_expansion * m.compress_size + GZIP_FREE_BYTES:
            raise InputFileError(str(path), f"holds {m.filename!r}, which expands {m.file_size:,} bytes from "
                                            f"{m.compress_size:,} (more than max_expansion {options.max_expansion:g} times): "
                                            f"a zip bomb, or data that compresses as no city model does")


def _extract(archive: zipfile.ZipFile, member: zipfile.ZipInfo, folder: Path) -> None:
    """Extract one member beneath ``folder`` (its name made relative), at most its declared size."""
    parts = [p for p in Path(member.filename.replace("\\", "/")).parts if p not in ("", ".", "..", "/")]
    if not parts:
        return
    target = folder.joinpath(*parts)
    if not target.resolve().is_relative_to(folder.resolve()):
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    left = member.file_size
    with archive.open(member) as src, open(target, "wb") as dst:
        while left > 0:
            chunk = src.read(min(COPY_CHUNK_BYTES, left))
            if not chunk:
                break
            dst.write(chunk)
            left -= len(chunk)


def open_zip(path: Path, what: str = "a zip archive") -> zipfile.ZipFile:
    """The zip file at ``path``; InputFileError saying it cannot be read as ``what`` otherwise."""
    try:
        return zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError) as err:
        raise InputFileError(str(path), f"cannot be read as {what} ({type(err).__name__}: {err})") from None


def expanded_size(path: Path) -> int:
    """The bytes a zip archive's members take extracted (their declared sizes); InputFileError where it is no zip."""
    with open_zip(path) as archive:
        return sum(m.file_size for m in archive.infolist() if not m.is_dir())


def extract_archive(path: Path, folder: Path, options) -> list:
    """Extract a zip archive beneath ``folder`` (as the module says: sizes checked first, names made relative) and
    list what it holds as a folder is listed (:func:`meshsom.io.expand_inputs`).

    Returns
    -------
    list of meshsom.io.InputFile
        The files to read, beneath ``folder``.

    Raises
    ------
    InputFileError
        Not a zip, too large, a zip bomb, cannot be extracted, or nothing in it that meshsom reads.
    """
    from meshsom.io import expand_inputs

    with open_zip(path) as archive:
        members = [m for m in archive.infolist() if not m.is_dir() and not m.filename.startswith("__MACOSX/")]
        _check_sizes(path, members, options)
        folder.mkdir(parents=True, exist_ok=True)
        try:
            for member in members:
                _extract(archive, member, folder)
        except (zipfile.BadZipFile, OSError, ValueError, NotImplementedError, RuntimeError) as err:
            raise InputFileError(str(path), f"cannot be extracted ({type(err).__name__}: {err})") from None
    skipped: list[tuple[str, str]] = []
    files, _ = expand_inputs([folder], skipped)
    if not files:
        held = ", ".join(sorted(m.filename for m in members)[:8]) or "nothing"
        raise InputFileError(str(path), f"holds no file that meshsom reads (it holds {held})")
    return files


def is_nested_archive(member: Path) -> bool:
    """Whether a file found in an archive is an archive itself (listed, not opened)."""
    return member.name.lower().endswith((ZIP_SUFFIX, ".kmz"))


#: The reason a zip inside a zip is not read.
NESTED = "is a zip inside a zip; not opened (unzip the outer one)"


def as_member(item, folder: Path, path: Path):
    """An item read from an extracted file, its source (and, for a Rejection, its reason) naming the archive's member
    (``archive.zip!/<member path>``) where it named the extracted file."""
    from meshsom.io import Rejection

    if isinstance(item, Rejection):
        item = dataclasses.replace(item, reason=_source(item.reason, folder, path, anywhere=True))
    return dataclasses.replace(item, source=_source(item.source, folder, path))


def read_zip(path: Path, options, name: str | None = None) -> Iterator:
    """Read every readable file of a zip archive (as the module says): RawMesh or Rejection items.

    Raises
    ------
    InputFileError
        Not a zip, too large, a zip bomb, or nothing in it that meshsom reads.
    """
    from meshsom.io import Rejection, read_file

    name = name or path.name
    folder = Path(tempfile.mkdtemp(prefix="meshsom-zip-"))
    try:
        files = extract_archive(path, folder, options)
        options = _paired(options, [f.path for f in files])
        for f in files:
            member = f.path.relative_to(folder).as_posix()
            if is_nested_archive(f.path):
                yield Rejection(f"{name}/{member}", f"{path}!/{member}", NESTED)
                continue
            for item in read_file(f.path, options, f"{name}/{f.name}"):
                item = as_member(item, folder, path)
                yield item if isinstance(item, Rejection) or not _unplaced(item, f) else dataclasses.replace(
                    item, notes=(*item.notes, "KML: no Model of the archive's KML places it: in its own frame"))
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _paired(options, paths: list[Path]):
    """``options`` with the building parts among an archive's files paired with their buildings
    (:func:`meshsom.part_files.pair`: Overture's two downloads, an INSPIRE municipality's files, zipped), beside the
    run's own pairs."""
    from meshsom.part_files import pair

    inner = pair(paths, dataclasses.replace(options, part_files=(), building_files=()))
    if not inner.part_files:
        return options
    return dataclasses.replace(options, part_files=options.part_files + inner.part_files,
                               building_files=options.building_files + inner.building_files)


def _source(text: str, folder: Path, path: Path, anywhere: bool = False) -> str:
    """``text`` with the temporary folder replaced by ``archive.zip!`` (at its start, or
    ``anywhere``: a reason that names the file)."""
    for root in (str(folder.resolve()), str(folder)):
        if anywhere:
            text = text.replace(root, f"{path}!")
        elif text.startswith(root):
            return f"{path}!{text[len(root):]}"
    return text


def _unplaced(item, f) -> bool:
    """Whether a model read from a KMZ is one no KML Model places (the models a KML places are
    read through it: :func:`meshsom.kml.read_kml`)."""
    from meshsom.kml import KML_SUFFIX

    return ".kmz!" in item.source.lower() and f.path.suffix.lower() != KML_SUFFIX
