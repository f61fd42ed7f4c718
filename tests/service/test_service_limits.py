"""Limits against a real uvicorn: an oversize upload is refused while it streams (the
server answers 413 before the client has finished sending), and raw ``../`` artifact paths
sent verbatim on the wire never reach a file."""

from __future__ import annotations

import json
import socket

import pytest
from scenes import TINY_SPEC
from service_harness import CORNELL, Cluster, mark_succeeded


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


@pytest.fixture(scope="module")
def succeeded_job(api_only):
    """A job of the running API marked succeeded with a bundle on disk: the artifact route
    answers 409 ``not_ready`` for every name of an unfinished job, so only a finished one
    reaches the name guard."""
    from jobs.config import Settings

    c = api_only
    job_id = c.submit(TINY_SPEC, asset=CORNELL).json()["id"]
    settings = Settings(data_dir=c.data)
    mark_succeeded(settings.db_url, settings.artifacts, job_id)
    assert c.client.get(f"/v1/bakes/{job_id}/artifacts/manifest.json").status_code == 200
    return job_id


def _raw_get(c: Cluster, path: str) -> tuple[int, bytes]:
    """``GET path`` sent verbatim on the wire (no client normalisation of ``..``)."""
    with socket.create_connection(("127.0.0.1", c.port), timeout=30) as s:
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".encode())
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split(b"\r\n", 1)[0].split()[1]), body


#: Reach the route (no decoded "/"): the guard must answer exactly 400 bad_name.
GUARDED = ["..", "...", "%2e%2e", "%2E%2E", ".%2e", "..\\..\\jobs.db", "..%5c..%5cjobs.db",
           "%5cetc%5cpasswd", "C:%5Cjobs.db", "%00", "manifest.json%00", "a%00b",
           "..%252f..%252fjobs.db", ".hidden"]
#: Carry a "/" once decoded (raw, %2f, absolute): no route matches, the router's 404.
UNROUTED = ["../../jobs.db", "..%2F..%2Fjobs.db", "..%2fmanifest.json",
            "%2e%2e/%2e%2e/queue.db", "%2e%2e%2f%2e%2e%2finput%2fasset.glb", "/etc/passwd",
            "%2Fetc%2Fpasswd", "%2F%2Fjobs.db", "a%2Fb"]


@pytest.mark.parametrize("raw", GUARDED)
def test_raw_traversal_names_meet_the_guard(api_only, succeeded_job, raw):
    code, body = _raw_get(api_only, f"/v1/bakes/{succeeded_job}/artifacts/{raw}")
    assert code == 400, (raw, code, body[:200])
    assert json.loads(body)["error"]["code"] == "bad_name"


@pytest.mark.parametrize("raw", UNROUTED)
def test_raw_traversal_paths_match_no_route(api_only, succeeded_job, raw):
    code, body = _raw_get(api_only, f"/v1/bakes/{succeeded_job}/artifacts/{raw}")
    # no route: Starlette's 404, in the API's one error shape (service/errors.py)
    assert code == 404, (raw, code, body[:200])
    assert json.loads(body)["error"]["code"] == "not_found", (raw, body[:200])
