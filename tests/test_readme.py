"""The README says what the code does (issue 14): the service's settings table against
``jobs/config.py`` (names and numeric defaults), supervision and reaping under
``prtcore serve``, the keyframe ``--time`` policy, and the assets the intake loads."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from jobs.config import Settings

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
#: settings that are not for users
UNDOCUMENTED = {"fault_crash_stage"}
UNITS = {"": 1, "KiB": 1 << 10, "MiB": 1 << 20, "GiB": 1 << 30}


def _settings_table() -> dict[str, str]:
    """``PRT_NAME`` → its default cell, from the README's settings table."""
    rows = {}
    for line in README.splitlines():
        m = re.match(r"^\| `(PRT_[A-Z_]+)` \| ([^|]*) \|", line)
        if m:
            rows[m.group(1)] = m.group(2).strip()
    return rows


def test_settings_live_in_jobs_config():
    assert "service/config.py" not in README
    assert "`jobs/config.py`" in README


def test_every_setting_is_in_the_table_with_its_default():
    table = _settings_table()
    fields = Settings.model_fields
    names = {f"PRT_{name.upper()}" for name in fields if name not in UNDOCUMENTED}
    assert names == set(table), (names ^ set(table))
    for name, field in fields.items():
        if name in UNDOCUMENTED or not isinstance(field.default, int | float) \
                or isinstance(field.default, bool):
            continue
        cell = table[f"PRT_{name.upper()}"]
        m = re.fullmatch(r"([\d.]+)\s*(KiB|MiB|GiB)?", cell)
        assert m, f"PRT_{name.upper()}: default {cell!r} is not a number"
        assert float(m.group(1)) * UNITS[m.group(2) or ""] == field.default, (name, cell)


@pytest.mark.parametrize("needle", [
    "PRT_RESTART_BACKOFF_S", "PRT_RESTART_BACKOFF_MAX_S", "PRT_RESTART_RESET_AFTER_S",
    "`prtcore serve` supervises its workers", "restarted after a delay",
    "runs the lease reaper", "even when no worker is up", "die with `serve`",
])
def test_supervision_is_documented(needle):
    assert needle in README


@pytest.mark.parametrize("needle", [
    "KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_mesh_quantization",
    "gets flat normals",
])
def test_intake_formats_are_documented(needle):
    assert needle in README


def test_keyframe_time_policy_is_documented():
    text = " ".join(README.split())
    assert "A T outside the animation (below 0 or past its duration) is **not refused**" in text
    assert "the nearest keyframe (the first or the last) is used and one line on stderr" in text
    assert "stratified" in text
