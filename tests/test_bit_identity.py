"""Same asset + spec + seed → the bundle recorded in tests/data/bundle_checksums.json.

Guards refactors (issue 12): every result file of three bakes (the Cornell example spec and
two shared assets) must keep its SHA-256. A deliberate numerical change re-records with
``python tests/bit_identity.py record`` and says so in its commit.
"""

from __future__ import annotations

import pytest
from bit_identity import SIMD_TIERS, bake_checksums, cases, platform_key, recorded


@pytest.mark.parametrize("name", sorted(cases()))
def test_bundle_checksums_unchanged(name, tmp_path):
    """The bundle matches the one recorded on this platform or on another (the module
    docstring of tests/bit_identity.py says why there are several)."""
    got = bake_checksums(name, tmp_path)
    platforms = recorded()
    if any(p.get(name) == got for p in platforms.values()):
        return

    def changed(key: str) -> list[str]:
        expected = platforms[key][name]
        return sorted(f for f in expected.keys() | got.keys() if expected.get(f) != got.get(f))

    mine = platform_key()
    key = mine if mine in platforms else min(sorted(platforms), key=lambda k: len(changed(k)))
    pytest.fail(f"{name}: files differ from the bundle recorded on {key} (this machine: "
                f"{mine}; recorded: {', '.join(sorted(platforms))}): {changed(key)}. On a "
                f"new platform with the code unchanged: python tests/bit_identity.py record "
                f"--add")


def test_the_record_is_one_set_per_platform():
    platforms = recorded()
    assert platforms and all(set(p) == set(cases()) for p in platforms.values())
    arch, simd, blas = platform_key().split("-")
    assert arch and blas and simd in {label for label, _ in SIMD_TIERS} | {"baseline"}
