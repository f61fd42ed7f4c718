#!/usr/bin/env python
"""Regenerate the golden images of tests/test_render.py, tests/test_viewer.py and
tests/test_hairbake.py and tests/test_hair_mesh.py (the GL hair drawings), and write a
difference report.

    .venv/bin/python scripts/regen_goldens.py [--dry-run] [-k EXPR]

Runs the golden tests with ``PRT_GOLDEN_RENDERS`` pointing at a temporary folder (the tests
still compare, and fail where the render changed: that is expected here), then, for every
render: writes ``tests/_golden_report/<name>_{before,after,diff}.png`` and a line of
``tests/_golden_report/report.md`` (pixels beyond the tolerance, largest difference,
whether the old golden would still pass), and copies the render over
``tests/goldens/<name>.png`` and the viewer's page screenshot over ``docs/viewer.png`` (the
README's; not with ``--dry-run``). Look at the report before committing
new goldens, and say in the commit what changed and why.

Exit status: 0 when every golden view was rendered (changed or not), 1 when a golden test
failed for another reason than its comparison, or rendered nothing.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
GOLDENS = TESTS / "goldens"
REPORT = TESTS / "_golden_report"
#: The README's screenshot of the web viewer, taken by tests/test_viewer.py's golden test.
PAGE_SHOT = ROOT / "docs" / "viewer.png"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dry-run", action="store_true", help="report only; keep the goldens")
    ap.add_argument("-k", default="golden_cornell or golden_shared_asset or golden_viewer or "
                    "golden_hair",
                    help="pytest -k expression selecting the golden tests")
    args = ap.parse_args(argv)

    sys.path.insert(0, str(TESTS))
    from golden_images import GOLDEN_OUTLIERS, GOLDEN_TOLERANCE, compare_to_golden

    from prtcore.io.imageio import read_image, write_png

    with tempfile.TemporaryDirectory(prefix="goldens.") as tmp:
        renders = Path(tmp)
        env = {k: v for k, v in os.environ.items() if not k.startswith("PRT_")}
        env["PRT_GOLDEN_RENDERS"] = str(renders)
        env["COLUMNS"] = "1000"  # pytest cuts the summary's messages to the terminal width
        log = renders / "pytest.log"
        with open(log, "w") as f:
            proc = subprocess.run(
                [sys.executable, "-m", "pytest", "-q", "-m", "", "-p", "no:cacheprovider",
                 "tests/test_render.py", "tests/test_viewer.py", "tests/test_hairbake.py",
                 "tests/test_hair_mesh.py",
                 "-k", args.k], cwd=ROOT,
                env=env, stdout=f,
                stderr=subprocess.STDOUT)
        text = log.read_text(errors="replace")
        made = sorted(p for p in renders.glob("*.png") if p.name != "viewer_page.png")
        failed = [ln for ln in text.splitlines() if ln.startswith(("FAILED", "ERROR"))]
        other = [ln for ln in failed if "pixels differ" not in ln and "shape" not in ln
                 and "missing: create it" not in ln]
        if not made or other:
            sys.stderr.write(text[-6000:])
            sys.stderr.write(f"\nregen_goldens: pytest exit {proc.returncode}; "
                             f"{len(made)} renders; failures other than a changed image:\n  "
                             + "\n  ".join(other or ["(no render was produced)"]) + "\n")
            return 1

        if REPORT.exists():
            shutil.rmtree(REPORT)
        REPORT.mkdir(parents=True)
        lines = ["# Golden images: before / after",
                 "",
                 f"Tolerance {GOLDEN_TOLERANCE}/255 per channel, {GOLDEN_OUTLIERS:.0%} of the "
                 "pixels may exceed it. Images: `<name>_before.png` (the committed golden), "
                 "`<name>_after.png` (this render), `<name>_diff.png` (|after − before| × 8).",
                 "",
                 "| golden | size | pixels beyond tolerance | max diff | old golden passes |",
                 "|---|---|---|---|---|"]
        for png in made:
            name = png.stem
            after = np.round(read_image(png) * 255).astype(np.uint8)
            write_png(REPORT / f"{name}_after.png", after)
            old = GOLDENS / f"{name}.png"
            if old.is_file():
                before = np.round(read_image(old) * 255).astype(np.uint8)
                write_png(REPORT / f"{name}_before.png", before)
                ok, _msg, diff = compare_to_golden(after, before)
                if diff is not None:
                    write_png(REPORT / f"{name}_diff.png", diff)
                    d = np.abs(after.astype(int) - before.astype(int)).max(axis=2)
                    frac, peak = f"{(d > GOLDEN_TOLERANCE).mean():.3%}", str(int(d.max()))
                else:
                    frac, peak = "shape changed", "–"
                lines.append(f"| {name} | {after.shape[1]}×{after.shape[0]} | {frac} | {peak}"
                             f" | {'yes' if ok else 'NO'} |")
            else:
                lines.append(f"| {name} | {after.shape[1]}×{after.shape[0]} | new | – | – |")
            if not args.dry_run:
                GOLDENS.mkdir(exist_ok=True)
                write_png(old, after)
        lines += ["", "Goldens " + ("not written (--dry-run)." if args.dry_run
                                    else f"written to {GOLDENS.relative_to(ROOT)}/.")]
        shot = renders / "viewer_page.png"
        if shot.is_file() and not args.dry_run:
            shutil.copyfile(shot, PAGE_SHOT)
            lines.append(f"README screenshot written to {PAGE_SHOT.relative_to(ROOT)}.")
        (REPORT / "report.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
        print("\n".join(lines))
        print(f"\nreport: {REPORT / 'report.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
