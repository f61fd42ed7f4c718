"""Embedded mode end to end with real processes: uvicorn API + ``prtcore worker``, SQLite
job store and queue, artifacts in a temp folder."""

from __future__ import annotations

import io
import json
import subprocess
import sys
import zipfile

import numpy as np
from service_harness import CORNELL, ROOT, SHELL_SPEC


def test_submit_poll_download_relight(make_cluster, shared_assets, tmp_path):
    """A shared asset (Duck) goes queued → running → succeeded; the zip holds the bundle;
    `prtcore relight` works on it; every listed artifact downloads with its checksum;
    an identical resubmission returns the same job and bakes nothing more."""
    c = make_cluster()
    c.start_api()
    c.start_worker()
    duck = shared_assets / "Duck.glb"
    r = c.submit(SHELL_SPEC, asset=duck)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    assert r.headers["location"] == f"/v1/bakes/{job_id}"
    assert r.json()["status"] == "queued"
    job = c.wait(job_id)
    assert job["status"] == "succeeded", job
    assert job["attempts"] == 1 and job["progress"] == 1.0 and job["error"] is None
    assert {"load", "texels", "fit", "export"} <= set(job["timings"])

    again = c.submit(SHELL_SPEC, asset=duck)
    assert again.status_code == 200 and again.json()["id"] == job_id

    listing = c.client.get(f"/v1/bakes/{job_id}/artifacts").json()
    names = {f["name"] for f in listing["files"]}
    assert {"manifest.json", "asset.glb", "basis_00.exr", "report.json"} <= names
    import hashlib
    manifest = c.client.get(f"/v1/bakes/{job_id}/artifacts/manifest.json").json()
    for name, meta in manifest["checksums"].items():
        body = c.client.get(f"/v1/bakes/{job_id}/artifacts/{name}").content
        assert hashlib.sha256(body).hexdigest() == meta["sha256"], name

    z = c.client.get(f"/v1/bakes/{job_id}/artifacts/bundle.zip")
    assert z.status_code == 200 and z.headers["content-type"] == "application/zip"
    bundle = tmp_path / "downloaded"
    zipfile.ZipFile(io.BytesIO(z.content)).extractall(bundle)
    assert set(p.name for p in bundle.iterdir()) == names
    report = c.client.get(f"/v1/bakes/{job_id}/report").json()
    assert report == json.loads((bundle / "report.json").read_text())

    light = tmp_path / "light.json"
    light.write_text(json.dumps({"type": "point", "color": [1, 1, 1], "intensity": 5.0,
                                 "position": [0.0, 150.0, 100.0]}))
    out = tmp_path / "relit.exr"
    p = subprocess.run([sys.executable, "-m", "prtcore", "relight", str(bundle), "--light",
                        str(light), "--out", str(out)], cwd=ROOT, capture_output=True,
                       text=True)
    assert p.returncode == 0, p.stderr

    # What the result must be: the bundle the library bakes from the same asset + spec
    # (bakes are bit-identical for the same inputs and seed), its manifest as the spec
    # says, and the relit file equal to the library's relight of the downloaded bundle.
    from prtcore import pipeline
    from prtcore.core.raytrace import RayTracer
    from prtcore.core.spec import parse_spec
    from prtcore.emitters.lightfile import load_light_file
    from prtcore.io.bundle import load_runtime, read_manifest
    from prtcore.io.gltf.loader import load_asset
    from prtcore.io.imageio import read_image
    from prtcore.runtime.cpu import relight

    local = pipeline.bake(duck, parse_spec(SHELL_SPEC), tmp_path / "local", quiet=True)
    lm = read_manifest(local)
    assert manifest["spec_sha256"] == lm["spec_sha256"]
    assert manifest["asset"]["sha256"] == hashlib.sha256(duck.read_bytes()).hexdigest()
    assert manifest["asset"]["source"] == "Duck.glb"  # the upload's name, not asset.glb
    assert manifest["asset"]["triangles"] == lm["asset"]["triangles"] > 0
    assert (manifest["atlas"]["width"], manifest["atlas"]["height"]) == (32, 32)
    assert manifest["atlas"]["padding"] == 2 and manifest["atlas"]["uv"] == "TEXCOORD_1"
    assert manifest["basis"]["count"] == 4 and manifest["fit"]["n_basis"] == 4
    assert manifest["points"]["count"] == 32
    assert manifest["fit"]["configurations"] == 16 and manifest["fit"]["used"] == 16
    result = [n for n in lm["checksums"] if n != "asset.glb"]
    assert {n: manifest["checksums"][n] for n in result} == \
        {n: lm["checksums"][n] for n in result}

    m = read_manifest(bundle)
    data = load_runtime(bundle, m)
    scene = load_asset(bundle / m["asset"]["file"])
    want = relight(data, load_light_file(light), RayTracer(scene.positions, scene.faces,
                                                             scene.radius))
    got = read_image(out)
    assert got.shape == want.shape == (32, 32, 4)
    covered = want[:, :, 3] > 0
    assert np.isfinite(got).all() and got[covered][:, :3].max() > 0
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7 * float(np.abs(want).max()))

    # Exactly one bundle, nothing half-written, the job counted in the metrics.
    assert sorted(p.name for p in c.job_dir(job_id).iterdir()) == ["bundle", "bundle.zip",
                                                                   "input"]
    metrics = c.client.get("/metrics").text
    assert 'prtcore_jobs{state="succeeded"} 1.0' in metrics
    assert "prtcore_bake_duration_seconds_count 1.0" in metrics
    assert CORNELL.exists()


def test_prtcore_serve_runs_everything_and_stops_cleanly(tmp_path):
    """`prtcore serve` alone: API + worker, embedded SQLite store and queue under
    PRT_DATA_DIR; a bake succeeds; SIGTERM stops the API and every worker process."""
    import os
    import signal
    import time

    import httpx
    from scenes import TINY_SPEC
    from service_harness import alive, descendants, free_port

    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("PRT_")}
    env.update(PRT_DATA_DIR=str(tmp_path / "data"), PRT_POLL_MAX_DELAY_S="0.2")
    log = open(tmp_path / "serve.log", "wb")  # closed below
    proc = subprocess.Popen([sys.executable, "-m", "prtcore", "serve", "--port", str(port),
                             "--workers", "1"], cwd=ROOT, env=env, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60) as c:
            for _ in range(600):
                try:
                    if c.get("/readyz").status_code == 200:
                        break
                except httpx.TransportError:
                    time.sleep(0.1)
            with open(CORNELL, "rb") as f:
                r = c.post("/v1/bakes", files={"asset": ("cornell.glb", f),
                                               "spec": ("s.json", json.dumps(TINY_SPEC))})
            assert r.status_code == 202, r.text
            job_id = r.json()["id"]
            for _ in range(2400):
                job = c.get(f"/v1/bakes/{job_id}").json()
                if job["status"] in ("succeeded", "failed", "cancelled"):
                    break
                time.sleep(0.1)
            assert job["status"] == "succeeded", job
        kids = descendants(proc.pid)
        assert kids, "serve started no worker process"
        assert (tmp_path / "data" / "jobs.db").is_file()
        assert (tmp_path / "data" / "queue.db").is_file()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0
        for _ in range(300):
            if not alive(kids):
                break
            time.sleep(0.1)
        assert not alive(kids), f"processes left behind: {alive(kids)}"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
        log.close()


def test_keyframe_bakes_through_the_service(make_cluster, shared_assets, tmp_path):
    """Animated assets as jobs (issue 7): a skinned asset built here and the milk truck
    (node TRS animation) both bake with keyframes through the API and a worker; the
    downloaded bundles carry their keyframes and relight at a time with the CLI."""
    tests_dir = ROOT / "tests"
    if str(tests_dir) not in sys.path:
        sys.path.insert(0, str(tests_dir))
    from keyframe_assets import bending_column_asset

    skinned = bending_column_asset(tmp_path / "column.glb")
    spec = json.loads(json.dumps(SHELL_SPEC))
    spec["keyframes"] = {"animation": 0, "count": 2, "transfer": "per_keyframe"}
    spec["atlas"] = {"resolution": 128, "padding": 1}  # the truck's charts need room
    c = make_cluster()
    c.start_api()
    c.start_worker()
    jobs = {name: c.submit(spec, asset=asset) for name, asset in
            (("column", skinned), ("truck", shared_assets / "CesiumMilkTruck.glb"))}
    for name, r in jobs.items():
        assert r.status_code == 202, (name, r.text)
        job = c.wait(r.json()["id"])
        assert job["status"] == "succeeded", (name, job)
        assert "keyframes" in job["timings"], (name, job["timings"])
        z = c.client.get(f"/v1/bakes/{job['id']}/artifacts/bundle.zip")
        bundle = tmp_path / name
        zipfile.ZipFile(io.BytesIO(z.content)).extractall(bundle)
        manifest = json.loads((bundle / "manifest.json").read_text())
        assert manifest["keyframes"]["count"] == 2, name
        assert manifest["transfer"]["matrix"]["shape"][0] == 2, name
        light = bundle / "holdout_lights.json"  # its own held-out lights, together
        t_last = manifest["keyframes"]["times"][-1]
        out = tmp_path / f"{name}.exr"
        p = subprocess.run([sys.executable, "-m", "prtcore", "relight", str(bundle),
                            "--light", str(light), "--out", str(out), "--time", str(t_last)],
                           cwd=ROOT, capture_output=True, text=True)
        assert p.returncode == 0, (name, p.stderr)
        assert f"keyframe 1 at {t_last:g} s" in p.stdout, (name, p.stdout)


def test_hair_with_a_head_bakes_through_the_service(make_cluster, tmp_path):
    """A hair asset and its head (the 'mesh' part) as one job: the worker bakes them
    together and the downloaded bundle holds the head's lightmap and the strand texture,
    which `prtcore relight` writes (docs/hair.md)."""
    from prtcore.io.hair import write_hair
    from prtcore.scenes.hair import head_hair, write_head

    hair = write_hair(tmp_path / "hair.hair", head_hair(100, "curly", seed=4))
    head = write_head(tmp_path / "head.glb")
    spec = {"atlas": {"resolution": 32}, "hair": {"texels_per_strand": 4},
            "lights": {"count": 16, "holdout": 4},
            "measurement_points": {"count": 16, "supersample": 2},
            "transport": {"gather_rays": 16}, "fit": {"basis": 4}}
    c = make_cluster()
    c.start_api()
    c.start_worker()
    r = c.submit(spec, asset=hair, mesh=head)
    assert r.status_code == 202, r.text
    job = c.wait(r.json()["id"])
    assert job["status"] == "succeeded", job
    z = c.client.get(f"/v1/bakes/{job['id']}/artifacts/bundle.zip")
    bundle = tmp_path / "bundle"
    zipfile.ZipFile(io.BytesIO(z.content)).extractall(bundle)
    manifest = json.loads((bundle / "manifest.json").read_text())
    assert manifest["asset"]["hair"]["strands"] == 100
    assert manifest["strands"]["basis_files"] and manifest["atlas"]["uv"] == "TEXCOORD_1"
    out = tmp_path / "relit.exr"
    p = subprocess.run([sys.executable, "-m", "prtcore", "relight", str(bundle), "--light",
                        str(bundle / "holdout_lights.json"), "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert out.is_file() and (tmp_path / "relit.strands.exr").is_file()
