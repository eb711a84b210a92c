"""A local HTTP server for the download tests (127.0.0.1, a free port, a thread): serves files held in memory, with
HEAD and single Range requests (206), and can misbehave on purpose: close the connection after a number of bytes
(`cut_after`, once), or ignore Range headers. It records every request's method, path and Range header."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


@dataclass
class Behaviour:
    files: dict[str, bytes] = field(default_factory=dict)  # path ("/a.zip") -> content
    cut_after: int | None = None  # the next GET sends this many bytes of its body, then closes (once)
    ignore_range: bool = False  # answer Range requests with the whole file (200)
    requests: list[tuple[str, str, str | None]] = field(default_factory=list)  # (method, path, Range header)


class LocalServer:
    """`with LocalServer() as server:` ... `server.url("/a.zip")`; `server.behaviour` is changed between requests."""

    def __init__(self) -> None:
        self.behaviour = Behaviour()
        behaviour = self.behaviour

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:  # quiet
                pass

            def _head(self, send_body: bool) -> None:
                behaviour.requests.append((self.command, self.path, self.headers.get("Range")))
                body = behaviour.files.get(self.path)
                if body is None:
                    self.send_error(404, "Not Found")
                    return
                start = 0
                ranged = self.headers.get("Range")
                if ranged and not behaviour.ignore_range:
                    start = int(ranged.removeprefix("bytes=").split("-")[0])
                    if start >= len(body):
                        self.send_response(416)
                        self.send_header("Content-Range", f"bytes */{len(body)}")
                        self.end_headers()
                        return
                    self.send_response(206)
                    self.send_header("Content-Range", f"bytes {start}-{len(body) - 1}/{len(body)}")
                else:
                    self.send_response(200)
                self.send_header("Content-Length", str(len(body) - start))
                self.send_header("Accept-Ranges", "bytes")
                self.end_headers()
                if not send_body:
                    return
                payload = body[start:]
                if behaviour.cut_after is not None:
                    payload, behaviour.cut_after = payload[: behaviour.cut_after], None
                    self.wfile.write(payload)
                    self.wfile.flush()
                    self.close_connection = True
                    return
                self.wfile.write(payload)

            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                self._head(send_body=True)

            def do_HEAD(self) -> None:  # noqa: N802
                self._head(send_body=False)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}{path}"

    def __enter__(self) -> LocalServer:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.shutdown()
        self.server.server_close()
