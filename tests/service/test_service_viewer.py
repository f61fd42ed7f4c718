"""The bake service's viewer (/v1/bakes/{id}/viewer) in a real browser: the page, its
scripts and the bundle all come from the app (Playwright routes every request of the page
through the app's TestClient), behind a bearer token that the browser context adds to every
request — as a proxy in front of the service would. The page loads the bake and relights
it; without the token the page is 401."""

from __future__ import annotations

import shutil
from urllib.parse import urlsplit

import pytest
from browser import launch, viewer_bundle, wait_ready
from service_harness import CORNELL, mark_succeeded

ORIGIN = "http://prt.test"
TOKEN = "s3cret"


@pytest.fixture
def finished_bake(app_client, tmp_path):
    """(client, job id): a succeeded job whose artifacts are a real (small) bundle."""
    c = app_client(api_tokens=[TOKEN])
    r = c.post("/v1/bakes", headers={"Authorization": f"Bearer {TOKEN}"},
               files={"asset": (CORNELL.name, CORNELL.read_bytes(), "application/octet-stream")})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    bundle = mark_succeeded(c.settings.db_url, c.settings.artifacts, job_id)
    shutil.rmtree(bundle)
    shutil.copytree(viewer_bundle(tmp_path / "bundle"), bundle)
    return c, job_id


def _through_app(client):
    def handle(route):
        req = route.request
        parts = urlsplit(req.url)
        headers = {k: v for k, v in req.headers.items() if k.lower() == "authorization"}
        r = client.get(parts.path + (f"?{parts.query}" if parts.query else ""),
                       headers=headers)
        route.fulfill(status=r.status_code, body=r.content,
                      headers={"content-type": r.headers.get("content-type", "text/plain")})
    return handle


@pytest.mark.slow  # a bake and a second browser (~25 s); the route itself: test_service_api
def test_service_viewer_loads_the_bake_behind_the_token(finished_bake):
    from playwright.sync_api import sync_playwright

    client, job_id = finished_bake
    errors: list[str] = []
    with sync_playwright() as pw:
        browser = launch(pw)
        try:
            bare = browser.new_context()
            bare.route(f"{ORIGIN}/**", _through_app(client))
            assert bare.new_page().goto(f"{ORIGIN}/v1/bakes/{job_id}/viewer").status == 401
            ctx = browser.new_context(
                extra_http_headers={"Authorization": f"Bearer {TOKEN}"})
            ctx.route(f"{ORIGIN}/**", _through_app(client))
            page = ctx.new_page()
            page.on("console", lambda m: m.type == "error" and errors.append(m.text))
            page.on("pageerror", lambda e: errors.append(str(e)))
            assert page.goto(f"{ORIGIN}/v1/bakes/{job_id}/viewer").status == 200
            wait_ready(page)
            r = page.evaluate("l => prt.setLight(l)", {"type": "point", "intensity": 2.0,
                                                       "position": [0.2, 1.4, 0.3]})
            assert r["s"] > 0 and any(r["u"])
        finally:
            browser.close()
    assert errors == []
