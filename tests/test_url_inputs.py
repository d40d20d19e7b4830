"""Inputs named by web URLs (``https://.../tile.city.json``, a folder's index page): the public downloads of city
models read without a manual download, through the mirror (meshsom.mirror), from a real web server on loopback
(the standard library's, serving a folder)."""

from __future__ import annotations

import functools
import http.server
import threading
from pathlib import Path

import pytest

from meshsom.store import read_manifest
from pipelines.cli import main

ROOT = Path(__file__).resolve().parents[1]
ZURICH = ROOT / "data" / "real" / "zurich-lod2-subset" / "zurich_subset_lod1_derived.city.json"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """A web server on a free loopback port serving a folder with the Zürich file in ``city/``; yields
    ``(base URL, folder)``."""
    folder = tmp_path_factory.mktemp("web")
    (folder / "city").mkdir()
    (folder / "city" / "zurich.city.json").write_bytes(ZURICH.read_bytes())
    handler = functools.partial(_Quiet, directory=str(folder))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}", folder
    finally:
        httpd.shutdown()
        httpd.server_close()


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):  # one line per request otherwise
        pass


@pytest.mark.parametrize("which", ["file", "folder"])
def test_a_download_url_is_read_as_the_same_file_on_disk(server, tmp_path, which):
    """`meshsom ingest URL` of a file, or of a folder's index page, gives the records of the same file on disk, the
    sources naming the URL; a URL the server does not have is a rejection naming it."""
    base, folder = server
    url = f"{base}/city/zurich.city.json" if which == "file" else f"{base}/city/"
    assert main(["ingest", url, "--out", str(tmp_path / "web.zarr"), "--json"]) == 0
    assert main(["ingest", str(folder / "city" / "zurich.city.json") if which == "file" else str(folder / "city"),
                 "--out", str(tmp_path / "disk.zarr"), "--json"]) == 0
    web, disk = read_manifest(tmp_path / "web.zarr")["records"], read_manifest(tmp_path / "disk.zarr")["records"]
    source = f"{base}/city/zurich.city.json"
    assert len(web) == 49 and {r["source"] for r in web} == {source}
    assert web == [{**r, "source": source} for r in disk]
    assert main(["ingest", f"{base}/city/missing.city.json", "--out", str(tmp_path / "none.zarr"), "--json"]) == 1
    (missing,) = read_manifest(tmp_path / "none.zarr")["records"]
    assert missing["source"] == f"{base}/city/missing.city.json" and "nothing under this URL" in missing["reason"]
