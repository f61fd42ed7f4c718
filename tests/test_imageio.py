"""EXR files as the bundle writes them (prtcore/io/imageio.py): what a browser's three.js
EXRLoader decodes (scanline, one part, half or float, ZIP), row 0 at the top (the manifest's
``atlas.exr_row_order``), lossy and undecodable compressions refused."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from prtcore.core.errors import PrtError
from prtcore.io.bundle import write_basis_files
from prtcore.io.imageio import EXR_COMPRESSIONS, EXR_ROW_ORDER, read_image, write_exr


def _spec(path) -> oiio.ImageSpec:
    inp = oiio.ImageInput.open(str(path))
    try:
        return inp.spec()
    finally:
        inp.close()


@pytest.mark.parametrize("dtype", ["half", "float"])
def test_basis_files_are_what_the_browser_reads(tmp_path, dtype):
    planes = np.random.default_rng(0).normal(size=(6, 5, 7)).astype(np.float32)
    names = write_basis_files(tmp_path, planes, dtype)
    assert names == ["basis_00.exr", "basis_01.exr"]
    for name in names:
        s = _spec(tmp_path / name)
        assert s.get_string_attribute("compression") == "zip"
        assert s.tile_width == 0 and s.get_int_attribute("oiio:subimages", 1) == 1
        assert s.get_string_attribute("openexr:lineOrder") == "increasingY"
        assert s.format == (oiio.HALF if dtype == "half" else oiio.FLOAT)


def test_row_zero_is_the_top_row(tmp_path):
    """EXR_ROW_ORDER top_down: image row 0 is the file's first scanline (data window y0 = 0,
    increasing y), read back as row 0."""
    img = np.zeros((4, 3, 1), np.float32)
    img[0, :, 0] = 1.0  # the top row only
    write_exr(tmp_path / "t.exr", img)
    assert EXR_ROW_ORDER == "top_down"
    back = read_image(tmp_path / "t.exr")
    np.testing.assert_array_equal(back[:, :, 0], img[:, :, 0])
    s = _spec(tmp_path / "t.exr")
    assert (s.y, s.get_string_attribute("openexr:lineOrder")) == (0, "increasingY")


@pytest.mark.parametrize("compression", ["dwaa", "dwab", "b44", "b44a", "pxr24", "htj2k"])
def test_lossy_and_undecodable_compressions_are_refused(tmp_path, compression):
    with pytest.raises(PrtError, match=f"compression '{compression}' is not written"):
        write_exr(tmp_path / "x.exr", np.zeros((2, 2, 4)), compression=compression)
    assert not (tmp_path / "x.exr").exists()


def test_accepted_compressions_round_trip(tmp_path):
    img = np.random.default_rng(1).normal(size=(8, 8, 4)).astype(np.float32)
    for c in EXR_COMPRESSIONS:
        write_exr(tmp_path / f"{c}.exr", img, compression=c)
        np.testing.assert_array_equal(read_image(tmp_path / f"{c}.exr"), img)
        assert _spec(tmp_path / f"{c}.exr").get_string_attribute("compression") == c
