"""simplenerf.data.downloads against a local HTTP server (tests/data/local_server.py): a whole download, one cut off
and resumed with a Range request, a server that ignores Range, a wrong size or SHA-256 (nothing under the final name),
and a server that cannot be reached. No network beyond 127.0.0.1."""

from __future__ import annotations

import hashlib
import os
import socket

import pytest

from simplenerf.data.downloads import (
    DownloadError,
    Expected,
    download_url,
    partial_path,
    read_json,
    remote_size,
    write_json,
)
from tests.data.local_server import LocalServer

BODY = os.urandom(3 * (1 << 20) + 12345)  # more than two read chunks
SHA = hashlib.sha256(BODY).hexdigest()


@pytest.fixture()
def server():
    with LocalServer() as s:
        s.behaviour.files["/file.bin"] = BODY
        yield s


def test_whole_download_is_checked_and_named_only_at_the_end(server, tmp_path):
    dest = tmp_path / "sub" / "file.bin"
    found = download_url(server.url("/file.bin"), dest, Expected(len(BODY), SHA), progress=False)
    assert (found.size, found.sha256) == (len(BODY), SHA)
    assert dest.read_bytes() == BODY
    assert not partial_path(dest).exists()
    assert remote_size(server.url("/file.bin")) == len(BODY)
    assert remote_size(server.url("/missing")) is None


def test_a_cut_download_resumes_with_a_range_request(server, tmp_path):
    dest = tmp_path / "file.bin"
    server.behaviour.cut_after = len(BODY) // 2
    with pytest.raises(DownloadError, match=rf"closed after {len(BODY) // 2} of {len(BODY)} bytes; run the same"):
        download_url(server.url("/file.bin"), dest, Expected(len(BODY), SHA), progress=False)
    assert not dest.exists()
    assert partial_path(dest).read_bytes() == BODY[: len(BODY) // 2]
    found = download_url(server.url("/file.bin"), dest, Expected(len(BODY), SHA), progress=False)
    assert found.sha256 == SHA and dest.read_bytes() == BODY
    assert server.behaviour.requests[-1] == ("GET", "/file.bin", f"bytes={len(BODY) // 2}-")


def test_a_server_that_ignores_range_sends_the_whole_file_again(server, tmp_path):
    dest = tmp_path / "file.bin"
    partial_path(dest).write_bytes(b"x" * 1000)  # not even a prefix of the file: must not survive
    server.behaviour.ignore_range = True
    download_url(server.url("/file.bin"), dest, Expected(sha256=SHA), progress=False)
    assert dest.read_bytes() == BODY
    assert server.behaviour.requests[-1][2] == "bytes=1000-"


def test_a_complete_partial_file_is_finished_without_a_body(server, tmp_path):
    dest = tmp_path / "file.bin"
    partial_path(dest).write_bytes(BODY)
    download_url(server.url("/file.bin"), dest, Expected(len(BODY), SHA), progress=False)  # the server answers 416
    assert dest.read_bytes() == BODY


def test_wrong_checksum_deletes_the_file_and_says_so(server, tmp_path):
    dest = tmp_path / "file.bin"
    wrong = "0" * 64
    with pytest.raises(DownloadError, match=f"has SHA-256 {SHA}, expected {wrong}; deleted it"):
        download_url(server.url("/file.bin"), dest, Expected(sha256=wrong), progress=False)
    assert not dest.exists() and not partial_path(dest).exists()


def test_wrong_size_is_refused_before_downloading(server, tmp_path):
    dest = tmp_path / "file.bin"
    with pytest.raises(DownloadError, match=f"the server offers {len(BODY)} bytes, expected 10; is it the right"):
        download_url(server.url("/file.bin"), dest, Expected(size=10), progress=False)
    assert not dest.exists()


def test_http_errors_and_unreachable_servers_are_one_line(server, tmp_path):
    with pytest.raises(DownloadError, match=r"/nothing: the server answered HTTP 404"):
        download_url(server.url("/nothing"), tmp_path / "x", progress=False)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DownloadError, match=rf"cannot reach http://127.0.0.1:{port}/x: .*refused"):
        download_url(f"http://127.0.0.1:{port}/x", tmp_path / "x", progress=False)
    assert not (tmp_path / "x").exists()


def test_manifest_json_round_trip(tmp_path):
    path = tmp_path / "manifest.json"
    assert read_json(path) == {}
    write_json(path, {"b": 1, "a": {"c": [1, 2]}})
    assert read_json(path) == {"a": {"c": [1, 2]}, "b": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json"]
