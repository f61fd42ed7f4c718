"""Where a job's files live under the artifact location (shared by API and workers).

``ARTIFACTS/<job id>/input/<asset>``  the upload as received (read by the worker)
``ARTIFACTS/<job id>/bundle/``        the bundle (docs/bundle.md), written atomically by bake
``ARTIFACTS/<job id>/bundle.zip``     the whole bundle as one download (temp + rename)
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import zipfile
from pathlib import Path

#: Names of files inside a bundle that may be served (one path segment, no leading dot).
SAFE_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}$")
ZIP_NAME = "bundle.zip"


def job_dir(root: Path, job_id: str) -> Path:
    return Path(root) / job_id


def input_dir(root: Path, job_id: str) -> Path:
    return job_dir(root, job_id) / "input"


def bundle_dir(root: Path, job_id: str) -> Path:
    return job_dir(root, job_id) / "bundle"


def zip_path(root: Path, job_id: str) -> Path:
    return job_dir(root, job_id) / ZIP_NAME


def clean_partials(root: Path, job_id: str) -> None:
    """Remove what an interrupted attempt may have left (temp bundle dirs, temp zips)."""
    d = job_dir(root, job_id)
    if not d.is_dir():
        return
    for p in d.iterdir():
        if p.name.startswith((".bundle.", ".bundle.zip")):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)


def write_zip(bundle: Path, dest: Path) -> Path:
    """Zip every file of ``bundle`` into ``dest`` atomically (temp file + rename)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".partial", dir=dest.parent)
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for p in sorted(bundle.iterdir()):
                if p.is_file():
                    zf.write(p, arcname=p.name)
        os.chmod(tmp, 0o644)
        os.replace(tmp, dest)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return dest


def check_writable(root: Path, job_id: str) -> None:
    """Raise ``OSError`` unless the job's folder can be created and written."""
    d = job_dir(root, job_id)
    d.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".write-test.", dir=d)
    os.close(fd)
    os.unlink(tmp)
