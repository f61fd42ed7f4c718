"""Limits against a real uvicorn: an oversize upload is refused while it streams (the
server answers 413 before the client has finished sending), and raw ``../`` artifact paths
sent verbatim on the wire never reach a file."""

from __future__ import annotations

import socket

import pytest
from service_harness import CORNELL, Cluster
from test_bundle import TINY_SPEC


def _recv_status(sock: socket.socket) -> str:
    data = b""
    while b"\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk:
            break
        data += chunk
    return data.split(b"\r\n", 1)[0].decode()


@pytest.fixture(scope="module")
def api_only(tmp_path_factory):
    c = Cluster(tmp_path_factory.mktemp("limits"), PRT_MAX_UPLOAD_BYTES="65536")
    try:
        c.start_api()
        yield c
    finally:
        c.close()


def test_oversize_chunked_upload_is_refused_while_streaming(api_only):
    """No Content-Length (chunked): the server reads up to the limit and answers 413 while
    the body is still open; nothing is left in the staging folder, no job is created."""
    c = api_only
    boundary = "prtboundary"
    head = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"asset\"; "
            f"filename=\"big.glb\"\r\nContent-Type: application/octet-stream\r\n\r\n").encode()
    with socket.create_connection(("127.0.0.1", c.port), timeout=30) as s:
        s.sendall((f"POST /v1/bakes HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n"
                   f"Content-Type: multipart/form-data; boundary={boundary}\r\n\r\n").encode())

        def chunk(b: bytes) -> None:
            s.sendall(f"{len(b):x}\r\n".encode() + b + b"\r\n")

        chunk(head)
        for _ in range(10):  # 160 kB of asset, limit 64 kB; the body is never terminated
            chunk(b"\0" * 16384)
        status = _recv_status(s)
    assert status.startswith("HTTP/1.1 413"), status
    assert not list((c.data / "artifacts" / ".uploads").iterdir())
    assert not any(j["asset"]["name"] == "big.glb" or j["asset"]["bytes"] > 65536
                   for j in c.client.get("/v1/bakes").json()["items"])


def test_declared_oversize_is_refused_before_reading(api_only):
    c = api_only
    with socket.create_connection(("127.0.0.1", c.port), timeout=30) as s:
        s.sendall(b"POST /v1/bakes HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000000\r\n"
                  b"Content-Type: multipart/form-data; boundary=b\r\n\r\n")
        assert _recv_status(s).startswith("HTTP/1.1 413")


@pytest.mark.parametrize("raw", ["../../jobs.db", "..%2F..%2Fjobs.db", "../input/asset.glb",
                                 "%2e%2e/%2e%2e/queue.db", "..\\..\\jobs.db"])
def test_raw_traversal_paths_never_serve_a_file(api_only, raw):
    c = api_only
    r = c.submit(TINY_SPEC, asset=CORNELL)
    job_id = r.json()["id"]
    with socket.create_connection(("127.0.0.1", c.port), timeout=30) as s:
        s.sendall(f"GET /v1/bakes/{job_id}/artifacts/{raw} HTTP/1.1\r\nHost: x\r\n"
                  f"Connection: close\r\n\r\n".encode())
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    status = data.split(b"\r\n", 1)[0].decode()
    code = int(status.split()[1])
    assert 400 <= code < 500, status
    assert b"SQLite format" not in data and b"glTF" not in data
