"""Files from the web, resumable and checked: `download_url` (plain HTTP(S), with Range requests) and
`download_drive` (Google Drive, through gdown), both writing `<name>.part`-style temporaries next to the file and
giving it its final name only once its size and SHA-256 are the expected ones, so that a file under its final name is
always complete. A cut download (network, Ctrl-C) resumes from its partial file when the same command runs again.

`publish` and `write_json` are the same rule for files this project writes itself: a temporary name, then a rename.
"""

from __future__ import annotations

import hashlib
import http.client
import json
import os
import sys
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from simplenerf.errors import DataError

CHUNK = 1 << 20  # bytes per read and write
USER_AGENT = "simplenerf-download"


class DownloadError(DataError):
    """A download failed (network, server, a cut connection) or gave the wrong bytes; the message says which file
    and whether running the command again resumes it."""


@dataclass(frozen=True)
class Expected:
    """What a downloaded file must be; None: not known, not checked (the digest is then printed for the record)."""

    size: int | None = None  # bytes
    sha256: str | None = None  # hex digest, lower case


@dataclass(frozen=True)
class Digest:
    """A file's size and SHA-256, as recorded in a manifest."""

    size: int
    sha256: str


def human(size: int | None) -> str:
    """A byte count for people: 1.5 GB, 300.0 MB, 12 B; 'unknown' for None."""
    if size is None:
        return "size unknown"
    value = float(size)
    for unit in ("B", "kB", "MB", "GB"):
        if value < 1000 or unit == "GB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1000
    raise AssertionError("unreachable")


def digest(path: Path) -> Digest:
    """The size and SHA-256 of a file."""
    sha = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(CHUNK), b""):
            sha.update(block)
    return Digest(path.stat().st_size, sha.hexdigest())


def check(path: Path, expected: Expected, what: str) -> Digest:
    """The file's digest; DownloadError naming `what` when its size or SHA-256 is not the expected one."""
    found = digest(path)
    if expected.size is not None and found.size != expected.size:
        raise DownloadError(f"{what}: {path} has {found.size} bytes, expected {expected.size}")
    if expected.sha256 is not None and found.sha256 != expected.sha256.lower():
        raise DownloadError(f"{what}: {path} has SHA-256 {found.sha256}, expected {expected.sha256.lower()}")
    return found


def partial_path(dest: Path) -> Path:
    """Where `download_url` keeps the bytes of `dest` received so far."""
    return dest.with_name(dest.name + ".part")


def remote_size(url: str, timeout: float = 10.0) -> int | None:
    """The Content-Length a HEAD request for `url` reports (None: no answer or none given); for --dry_run."""
    request = urllib.request.Request(url, method="HEAD", headers={"User-Agent": USER_AGENT})
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            length = response.headers.get("Content-Length")
    except (OSError, ValueError, http.client.HTTPException):
        return None
    return int(length) if length and length.isdigit() else None


def _open(url: str, start: int, timeout: float):
    """The response to a GET of `url` from byte `start` on (a Range request when start > 0)."""
    headers = {"User-Agent": USER_AGENT, "Accept-Encoding": "identity"}
    if start:
        headers["Range"] = f"bytes={start}-"
    try:
        return urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=timeout)
    except urllib.error.HTTPError as e:
        if e.code == 416 and start:  # Range Not Satisfiable: the partial file already holds every byte
            return None
        raise DownloadError(f"{url}: the server answered HTTP {e.code} {e.reason}") from None
    except (urllib.error.URLError, OSError, ValueError, http.client.HTTPException) as e:
        reason = getattr(e, "reason", None) or e
        raise DownloadError(f"cannot reach {url}: {reason}") from None


def download_url(url: str, dest: Path, expected: Expected = Expected(), timeout: float = 60.0,
                 progress: bool = True) -> Digest:
    """Downloads `url` to `dest` through `dest.part`, resuming a partial file with a Range request (a server that
    ignores it sends the whole file, which then replaces the partial one). `dest` appears only complete and checked;
    a file of the wrong size or SHA-256 is deleted. Returns the file's digest."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    part = partial_path(dest)
    start = part.stat().st_size if part.is_file() else 0
    if expected.size is not None and start > expected.size:
        part.unlink()  # longer than the file can be: not a prefix of it
        start = 0
    response = _open(url, start, timeout)
    if response is not None:
        with response:
            resumed = bool(start) and response.status == 206
            if resumed and not (response.headers.get("Content-Range") or "").startswith(f"bytes {start}-"):
                raise DownloadError(f"{url}: the server resumed at another byte than {start} "
                                    f"(Content-Range {response.headers.get('Content-Range')!r}); delete {part}")
            start = start if resumed else 0
            length = response.headers.get("Content-Length")
            total = start + int(length) if length and length.isdigit() else None
            if expected.size is not None and total is not None and total != expected.size:
                raise DownloadError(f"{url}: the server offers {total} bytes, expected {expected.size}; is it the "
                                    "right file?")
            received = 0
            try:
                with open(part, "ab" if resumed else "wb") as f, tqdm(
                    total=total, initial=start, unit="B", unit_scale=True, desc=dest.name, file=sys.stderr,
                    disable=not progress or None, leave=False,
                ) as bar:
                    while block := response.read(CHUNK):
                        f.write(block)
                        received += len(block)
                        bar.update(len(block))
            except (OSError, http.client.HTTPException) as e:
                raise DownloadError(f"{url}: the connection broke after {start + received} bytes ({e}); run the "
                                    f"same command again to resume from {part}") from None
            if total is not None and start + received < total:
                raise DownloadError(f"{url}: the connection closed after {start + received} of {total} bytes; run "
                                    f"the same command again to resume from {part}")
    return finish(part, dest, expected, url)


def finish(part: Path, dest: Path, expected: Expected, source: str) -> Digest:
    """Checks a complete download `part` and renames it to `dest`; a wrong one is deleted (DownloadError)."""
    size = part.stat().st_size
    if expected.size is not None and size < expected.size:
        raise DownloadError(f"{source}: {part} has {size} of {expected.size} bytes; run the same command again to "
                            "resume")
    try:
        found = check(part, expected, source)
    except DownloadError as e:
        part.unlink()
        raise DownloadError(f"{e}; deleted it (run again to download it anew, or check the URL)") from None
    os.replace(part, dest)
    return found


def download_drive(file_id: str, dest: Path, expected: Expected = Expected(), progress: bool = True) -> Digest:
    """Downloads a public Google Drive file through gdown (`pip install 'simplenerf[data]'`), resumable (gdown keeps
    `<name><8 characters>.part` next to it), then checks and renames it as `download_url` does."""
    try:
        import gdown
    except ImportError:
        raise DownloadError("downloading from Google Drive needs gdown: pip install 'simplenerf[data]' (or give a "
                            "mirror with --url, or the downloaded file with --archive)") from None
    dest.parent.mkdir(parents=True, exist_ok=True)
    unchecked = dest.with_name(dest.name + ".unchecked")
    try:
        gdown.download(id=file_id, output=str(unchecked), quiet=not progress, resume=True)
    except Exception as e:  # gdown's DownloadError / FileURLRetrievalError, requests' errors
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise DownloadError(f"Google Drive file {file_id}: {first}; run the same command again to resume, or give a "
                            "mirror with --url") from None
    return finish(unchecked, dest, expected, f"Google Drive file {file_id}")


def publish(tmp: Path, dest: Path) -> None:
    """Gives a finished temporary file or folder its final name (same folder, so the rename is atomic)."""
    os.replace(tmp, dest)


def write_json(path: Path, data: dict) -> None:
    """Writes a JSON file through a temporary name, so that it is never half-written."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    publish(tmp, path)


def read_json(path: Path) -> dict:
    """A manifest written by `write_json`, {} when there is none yet; DataError when it is not JSON."""
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise DataError(f"cannot read {path}: {e} (delete it and run the command again to rebuild it)") from e
