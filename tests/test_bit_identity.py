"""Same asset + spec + seed → the bundle recorded in tests/data/bundle_checksums.json.

Guards refactors (issue 12): every result file of three bakes (the Cornell example spec and
two shared assets) must keep its SHA-256. A deliberate numerical change re-records with
``python tests/bit_identity.py record`` and says so in its commit.
"""

from __future__ import annotations

import json

import pytest
from bit_identity import RECORD, bake_checksums, cases


@pytest.mark.parametrize("name", sorted(cases()))
def test_bundle_checksums_unchanged(name, tmp_path):
    expected = json.loads(RECORD.read_text())[name]
    got = bake_checksums(name, tmp_path)
    changed = sorted(f for f in expected.keys() | got.keys() if expected.get(f) != got.get(f))
    assert not changed, f"{name}: files differ from the recorded bundle: {changed}"
