"""``prtcore view DIR``: the viewer and one bundle on 127.0.0.1 (ES modules do not load from
``file://``). Serves ``/`` (the page), ``/static/<file>`` (the viewer's files),
``/bundle/<name>`` (plain files directly in the bundle directory, no links) and, when given,
``/reference/reference.exr`` and ``/reference/light.json``; everything else is 404.
"""

from __future__ import annotations

import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import unquote, urlsplit

from prtcore.core.errors import PrtError
from prtcore.io.bundle import read_manifest
from prtcore.viewer.page import viewer_content_type, viewer_page, viewer_static_path

HOST = "127.0.0.1"


def _handler(bundle: Path, quiet: bool, reference: dict[str, Path]
             ) -> type[BaseHTTPRequestHandler]:
    index = viewer_page("./static/", "./bundle/", "./reference/" if reference else ""
                        ).encode("utf-8")

    class Handler(BaseHTTPRequestHandler):
        server_version = "prtcore-view"

        def do_GET(self) -> None:
            path = unquote(urlsplit(self.path).path)
            if path in ("/", "/index.html"):
                return self._send(index, viewer_content_type("index.html"))
            if path.startswith("/static/"):
                f = viewer_static_path(path[len("/static/"):])
                return self._file(f)
            if path.startswith("/reference/"):
                return self._file(reference.get(path[len("/reference/"):]))
            if path.startswith("/bundle/"):
                name = path[len("/bundle/"):]
                ok = name and not any(c in name for c in "/\\\0") and not name.startswith(".")
                f = bundle / name if ok else None  # a plain file of the bundle, not a link
                return self._file(f if f is not None and f.is_file() and not f.is_symlink()
                                  else None)
            return self._file(None)

        def _file(self, f: Path | None) -> None:
            if f is None:
                self.send_error(HTTPStatus.NOT_FOUND, "not a viewer or bundle file")
                return
            self._send(f.read_bytes(), viewer_content_type(f.name))

        def _send(self, body: bytes, ctype: str) -> None:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args) -> None:
            if not quiet:
                super().log_message(format, *args)

    return Handler


class ViewerServer:
    """The viewer of the bundle ``directory`` on 127.0.0.1:``port`` (0: any free port).

    ``reference`` and ``reference_light``: a path-traced indirect lightmap of the bundle
    (``prtcore reference DIR --light L --out REF.exr``) and its light file, for the page's
    error heat map (served as /reference/reference.exr and /reference/light.json).
    ``url`` is the page; :meth:`serve_forever` blocks, :meth:`start` serves from a daemon
    thread, :meth:`close` stops. The bundle is checked (manifest.json) before binding.
    """

    def __init__(self, directory: str | Path, port: int = 0, quiet: bool = False,
                 reference: str | Path | None = None,
                 reference_light: str | Path | None = None):
        self.directory = Path(directory)
        read_manifest(self.directory)  # a clear error for a non-bundle, before binding
        if (reference is None) != (reference_light is None):
            raise PrtError("view: --reference and --light go together (the path-traced "
                           "lightmap and the light it was traced for)")
        ref = {}
        if reference is not None:
            ref = {"reference.exr": Path(reference), "light.json": Path(reference_light)}
            for f in ref.values():
                if not f.is_file():
                    raise PrtError(f"view: {f}: no such file")
        try:
            self.httpd = ThreadingHTTPServer((HOST, port),
                                             _handler(self.directory, quiet, ref))
        except OSError as e:
            raise PrtError(f"view: cannot listen on {HOST}:{port}: {e.strerror or e}") from None
        self.httpd.daemon_threads = True
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.httpd.server_address[1]}/"

    def serve_forever(self) -> None:
        self.httpd.serve_forever()

    def start(self) -> ViewerServer:
        self._thread = threading.Thread(target=self.httpd.serve_forever, daemon=True,
                                        name="prtcore-view")
        self._thread.start()
        return self

    def close(self) -> None:
        if self._thread is not None:
            self.httpd.shutdown()
            self._thread.join()
        self.httpd.server_close()

    def __enter__(self) -> ViewerServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
