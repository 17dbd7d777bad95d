"""The cube reader against ALE's own test data (tests/data/isis, see its README), instrument by
instrument: the camera read from a spiceinit'd cube projects ground points to the pixels that
the camera of ALE's ISD of the same image gives, within 0.01 px (both through
orthomvp.camera.csm), and the times that decide them agree.

Real spiceinit'd cubes (MRO CTX, LRO NAC, MESSENGER MDIS) are read as they are, edited only
where ALE's 1 x 1 copies of them (ISIS makecube + copylabel) need it; for the others (Dawn
FC, Kaguya TC, LRO WAC, Mars Express HRSC) the real ISIS label of the image, with the
NaifKeywords spiceinit wrote into it, gets the four SPICE tables written from ALE's ISD (its
labels come without the tables' bytes).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from orthomvp.camera.csm.isd import camera_from_isd
from orthomvp.camera.isis import cube_isd, read_cube_camera
from orthomvp.errors import FormatError
from tests.isis_ale import DATA, ale_isd, pixel_differences, real_cube, spice_cube

HEIGHTS = (0.0, 2000.0)


def _no_alpha(text: str) -> str:
    """``text`` without its AlphaCube group."""
    return re.sub(r"  Group = AlphaCube\n(?:.*\n)*?  End_Group\n", "", text)


def _size(samples: int, lines: int):
    def edit(text: str) -> str:
        text = re.sub(r"(Group = Dimensions\n\s*Samples = )\d+", rf"\g<1>{samples}", text)
        return re.sub(r"(\n\s*Lines   = )\d+", rf"\g<1>{lines}", text, count=1)

    return edit


def _swath(text: str, mode: str) -> str:
    """``text`` with its Instrument SwathModeId set to ``mode``."""
    return re.sub(r"SwathModeId\s+= \w+", f"SwathModeId = {mode}", text)


def _same_times(path: Path, isd: dict) -> None:
    """The cube's ISD starts (line scan) or is exposed (frame) when ALE's does, to 1 us."""
    ours = cube_isd(path)
    key = "starting_ephemeris_time" if "starting_ephemeris_time" in isd else "center_ephemeris_time"
    assert abs(ours[key] - isd[key]) < 1e-6, key
    if "line_scan_rate" in isd:
        assert abs(ours["line_scan_rate"][0][2] - isd["line_scan_rate"][0][2]) < 1e-12


def test_mro_ctx_real_cube(tmp_path: Path) -> None:
    """ALE's spiceinit'd CTX cube (1 x 1, its tables spanning the one line of the image;
    ALE's IsisSpice driver's ISD): across the whole detector swath, at two heights."""
    isd = ale_isd("mro_ctx", "ctx_isis_isd.json.gz")
    path = real_cube(tmp_path / "ctx.cub", "mro_ctx", "B10_013341_1010_XN_79S172W.cub.gz", str)
    _same_times(path, isd)
    for height in HEIGHTS:
        diff = pixel_differences(path, isd, height, samples=(0.0, 5000.0), lines=(0.0, 0.0))
        assert np.isfinite(diff).all() and diff.max() < 0.01


def test_lro_nac_real_cube(tmp_path: Path) -> None:
    """ALE's spiceinit'd NAC-L cube (ALE's IsisSpice driver's ISD). ALE's 1 x 1 copy carries
    an AlphaCube of the full image with its samples and lines swapped, which ALE ignores: it is
    dropped, and the image given the 52000 lines its tables cover, here and in the ISD."""
    isd = ale_isd("lro_nac", "lro_isis_isd.json.gz")
    isd["image_lines"] = isd["image_samples"] = 52000
    edit = lambda text: _size(52000, 52000)(_no_alpha(text))  # noqa: E731
    path = real_cube(tmp_path / "nac.cub", "lro_nac", "M103595705LE.cub.gz", edit)
    _same_times(path, isd)
    for height in HEIGHTS:
        diff = pixel_differences(path, isd, height, samples=(0.0, 5063.0), lines=(0.0, 51999.0))
        assert np.isfinite(diff).all() and diff.max() < 0.01


def test_messenger_mdis_nac(tmp_path: Path) -> None:
    """The label of ALE's spiceinit'd MDIS-NAC cube (FPU binning 2, a 512 x 512 image; ALE's
    1 x 1 copy's AlphaCube dropped) with the tables of ALE's ISD from NAIF kernels: the
    temperature-dependent focal length, the binning, the Taylor lens of ALE's ISD."""
    isd = ale_isd("messenger_mdis", "messmdis_isd.json.gz")
    cube = real_cube(tmp_path / "mdis.cub", "messenger_mdis", "EN1072174528M.cub.gz", str)
    label = cube.read_bytes()[: cube.read_bytes().index(b"\nEnd\n") + 5].decode("latin-1")
    edit = lambda text: _size(512, 512)(_no_alpha(text))  # noqa: E731
    path = spice_cube(tmp_path / "mdis_tables.cub", label, isd, edit=edit)
    _same_times(path, isd)
    ours = cube_isd(path)
    assert ours["focal_length_model"] == isd["focal_length_model"]
    assert ours["detector_line_summing"] == isd["detector_line_summing"] == 2
    for height in HEIGHTS:
        assert pixel_differences(path, isd, height).max() < 0.01


def test_dawn_fc(tmp_path: Path) -> None:
    """Dawn FC2 (filter 6): the real ISIS label with ALE's ISD's tables. ALE's ISIS-label
    driver for FC declares no lens (NoDistortion) where its PDS3 driver and ISIS
    (DawnFcDistortionMap) have the ``dawnfc`` one: with that lens put into ALE's ISD the two
    cameras agree; without it they differ by what the lens moves (under a pixel)."""
    isd = ale_isd("dawn_fc", "dawnfc_isis_isd.json.gz")
    label = (DATA / "dawn_fc" / "FC21A0038582_15170161546F6G_isis3.lbl").read_text()
    path = spice_cube(tmp_path / "fc.cub", label, isd)
    _same_times(path, isd)
    lens_free = pixel_differences(path, isd)
    assert 0.1 < lens_free.max() < 1.0
    coefficient = isd["naif_keywords"]["INS-203126_RAD_DIST_COEFF"]
    isd["optical_distortion"] = {"dawnfc": {"coefficients": [coefficient]}}
    for height in HEIGHTS:
        assert pixel_differences(path, isd, height).max() < 0.01


def test_kaguya_tc(tmp_path: Path) -> None:
    """Kaguya TC1 (FULL swath): the real ISIS label with ALE's ISD's tables: the clock time,
    the line sampling interval, the swath's first sample, the kaguyalism lens."""
    isd = ale_isd("kaguya_tc", "kaguyatc_isis_isd.json.gz")
    label = (DATA / "kaguya_tc" / "TC1S2B0_01_06691S820E0465_isis3.lbl").read_text()
    path = spice_cube(tmp_path / "tc.cub", label, isd)
    _same_times(path, isd)
    ours, theirs = cube_isd(path)["optical_distortion"], isd["optical_distortion"]
    for key in ("x", "y", "boresight_x", "boresight_y"):
        np.testing.assert_allclose(ours["kaguyalism"][key], theirs["kaguyalism"][key], rtol=1e-12)
    for height in HEIGHTS:
        assert pixel_differences(path, isd, height).max() < 0.01


@pytest.mark.parametrize(("swath", "first"), [("NOMINAL", 296.5), ("HALF", 1171.5)])
def test_kaguya_tc_swath_modes(tmp_path: Path, swath: str, first: float) -> None:
    """A narrower swath starts further along the detector (ISIS's first pixels 297, 1172)."""
    isd = ale_isd("kaguya_tc", "kaguyatc_isis_isd.json.gz")
    label = (DATA / "kaguya_tc" / "TC1S2B0_01_06691S820E0465_isis3.lbl").read_text()
    path = spice_cube(tmp_path / "tc.cub", label, isd, edit=lambda text: _swath(text, swath))
    assert cube_isd(path)["starting_detector_sample"] == first
    isd["starting_detector_sample"] = first
    assert pixel_differences(path, isd).max() < 0.01


def test_lro_wac_uv_push_frame(tmp_path: Path) -> None:
    """LRO WAC-UV (even framelets, filter 1 of 2 bands): the first of the real ISIS labels
    that ALE's file holds, with ALE's ISD's tables: the push-frame timing (clock start + half
    an exposure, the interframe delay), 4 x 4 summing, the filter's offset on the detector,
    origin, focal plane and negated radial lens. Where framelets overlap, projecting is not
    the inverse of image to ground (in usgscsm too), so the two cameras' projections of the
    same ground points are compared, and their ground points of the same pixels."""
    isd = ale_isd("lro_wac", "lrolrocwac_isd.json.gz")
    label = (DATA / "lro_wac" / "wac0000a1c4.uv.even_isis3.lbl").read_text()
    path = spice_cube(tmp_path / "wac.cub", label, isd)
    _same_times(path, isd)
    ours = cube_isd(path)
    for key in ("ending_ephemeris_time", "exposure_duration", "interframe_delay"):
        assert abs(ours[key] - isd[key]) < 1e-6, key
    for key in ("framelet_height", "starting_detector_line", "detector_line_summing"):
        assert ours[key] == isd[key], key
    for height in HEIGHTS:
        assert pixel_differences(path, isd, height).max() < 0.01


def test_lro_wac_refuses_a_cropped_cube(tmp_path: Path) -> None:
    """A push-frame cube cropped (AlphaCube) no longer holds whole framelets: one line."""
    isd = ale_isd("lro_wac", "lrolrocwac_isd.json.gz")
    label = (DATA / "lro_wac" / "wac0000a1c4.uv.even_isis3.lbl").read_text()
    alpha = (
        "  Group = AlphaCube\n    AlphaSamples = 128\n    AlphaLines = 1040\n"
        "    AlphaStartingSample = 0.5\n    AlphaStartingLine = 2.5\n"
        "    AlphaEndingSample = 128.5\n    AlphaEndingLine = 1042.5\n"
        "    BetaSamples = 128\n    BetaLines = 1040\n  End_Group\nEnd_Object\n"
    )
    path = spice_cube(
        tmp_path / "wac.cub",
        label,
        isd,
        edit=lambda text: text[: text.rindex("End_Object")] + alpha,
    )
    with pytest.raises(FormatError, match="cropped or reduced push-frame cube") as info:
        cube_isd(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def _hrsc(tmp_path: Path, edit=str) -> tuple[Path, dict]:
    """The HRSC IR cube: the real ISIS label with ALE's ISD's tables and the LineScanTimes
    table of ALE's test (its three rates: ALE's test_mex_load gives them to its driver)."""
    isd = ale_isd("mex_hrsc", "mexhrsc_isis_isd.json.gz")
    label = (DATA / "mex_hrsc" / "h5270_0000_ir2_isis3.lbl").read_text()
    times = {
        "EphemerisTime": np.array([255744599.02748165, 255744684.33197814, 255744684.34504557]),
        "ExposureTime": np.array(
            [0.012800790786743165, 0.012907449722290038, 0.013227428436279297]
        ),
        "LineStart": np.array([1, 6665, 6666], dtype=np.int32),
    }
    tables = (("LineScanTimes", {}, times),)
    return spice_cube(tmp_path / "hrsc.cub", label, isd, edit=edit, tables=tables), isd


def test_mex_hrsc_variable_line_rate(tmp_path: Path) -> None:
    """HRSC's IR line (summing 4): the line rate changing twice, from the cube's
    LineScanTimes table; the filter's focal plane and origin."""
    path, isd = _hrsc(tmp_path)
    _same_times(path, isd)
    ours = cube_isd(path)
    np.testing.assert_allclose(ours["line_scan_rate"], isd["line_scan_rate"], rtol=0, atol=1e-9)
    assert ours["center_ephemeris_time"] == pytest.approx(isd["center_ephemeris_time"], abs=1e-6)
    for height in HEIGHTS:
        assert pixel_differences(path, isd, height).max() < 0.01


@pytest.mark.parametrize("slope", [1.0, 2.0])
def test_mex_hrsc_crop_across_a_rate_change(tmp_path: Path, slope: float) -> None:
    """A crop (and a 2x reduction) of the HRSC cube starting at line 6001, across the rate
    changes at lines 6665 and 6666: the cube's pixel (u, v) is the original image's
    (slope (u + 0.5) + a0 - 1) on each axis, a0 the AlphaCube's start (ISIS's AlphaCube)."""
    a0_s, a0_l, beta_s, beta_l = 100.5, 6000.5, 400, 1000

    def crop(text: str) -> str:
        text = _size(beta_s, beta_l)(text)
        alpha = (
            f"  Group = AlphaCube\n    AlphaSamples = 1288\n    AlphaLines = 15088\n"
            f"    AlphaStartingSample = {a0_s}\n    AlphaStartingLine = {a0_l}\n"
            f"    AlphaEndingSample = {a0_s + slope * beta_s}\n"
            f"    AlphaEndingLine = {a0_l + slope * beta_l}\n"
            f"    BetaSamples = {beta_s}\n    BetaLines = {beta_l}\n  End_Group\n"
        )
        return text[: text.rindex("End_Object")] + alpha + "End_Object\n"

    path, isd = _hrsc(tmp_path, crop)
    ours, full = read_cube_camera(path), camera_from_isd(isd)
    u, v = np.meshgrid(np.linspace(0, beta_s - 1, 7), np.linspace(0, beta_l - 1, 31))
    uv = np.stack([u.ravel(), v.ravel()], -1)
    in_full = slope * (uv + 0.5) + np.array([a0_s, a0_l]) - 1.0
    ground = full.image_to_ground(in_full, 0.0)
    assert np.abs(ours.project(ground)[0] - uv).max() < 0.01


def _kaguya(tmp_path: Path, edit=str) -> Path:
    isd = ale_isd("kaguya_tc", "kaguyatc_isis_isd.json.gz")
    label = (DATA / "kaguya_tc" / "TC1S2B0_01_06691S820E0465_isis3.lbl").read_text()
    return spice_cube(tmp_path / "tc.cub", label, isd, edit=edit)


def _wac(tmp_path: Path, edit=str) -> Path:
    isd = ale_isd("lro_wac", "lrolrocwac_isd.json.gz")
    label = (DATA / "lro_wac" / "wac0000a1c4.uv.even_isis3.lbl").read_text()
    return spice_cube(tmp_path / "wac.cub", label, isd, edit=edit)


def _hirise(tmp_path: Path) -> Path:
    isd = ale_isd("kaguya_tc", "kaguyatc_isis_isd.json.gz")  # any tables: refused before them
    label = (DATA / "mro_hirise" / "PSP_001446_1790_BG12_0_isis3.lbl").read_text()
    return spice_cube(tmp_path / "hirise.cub", label, isd)


def _hrsc_without_times(tmp_path: Path) -> Path:
    isd = ale_isd("mex_hrsc", "mexhrsc_isis_isd.json.gz")
    label = (DATA / "mex_hrsc" / "h5270_0000_ir2_isis3.lbl").read_text()
    return spice_cube(tmp_path / "hrsc.cub", label, isd)


def _hrsc_truncated(tmp_path: Path) -> Path:
    path, _ = _hrsc(tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[:-30])  # LineScanTimes is the last table: half its bytes are gone
    return path


BAD = {
    "hirise-unsupported": (
        _hirise,
        r"instrument 'HIRISE' of 'MARS RECONNAISSANCE ORBITER' is not supported .*"
        r"give an ISD from ALE's isd_generate instead",
    ),
    "hrsc-no-line-times": (
        _hrsc_without_times,
        r"no Table LineScanTimes: HRSC's line times, which hrsc2isis writes",
    ),
    "hrsc-truncated-line-times": (_hrsc_truncated, r"truncated Table LineScanTimes"),
    "kaguya-swath": (
        lambda tmp: _kaguya(tmp, lambda text: _swath(text, "WIDE")),
        r"Instrument SwathModeId = 'WIDE' is not one of",
    ),
    "kaguya-lines-beyond-tables": (
        lambda tmp: _kaguya(tmp, lambda text: _no_alpha(_size(3208, 4656)(text))),
        r"the cube's lines are exposed over ET \[.*\], beyond its instrument_pointing table",
    ),
    "wac-filter": (
        lambda tmp: _wac(
            tmp, lambda text: text.replace("FilterNumber = (1, 2)", "FilterNumber = 5")
        ),
        r"BandBin FilterNumber = 5 is not a filter of the WAC-UV camera",
    ),
    "wac-framelets": (
        lambda tmp: _wac(tmp, _size(128, 1041)),
        r"the cube's 1041 lines are not whole framelets of 4 lines",
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_cubes_of_the_new_instruments(
    tmp_path: Path, capsys: pytest.CaptureFixture, case: str
) -> None:
    """One line naming the cube and what is wrong, from the API (the orthomvp.errors family)
    and from `orthomvp isd` (exit status 2, no ISD written)."""
    from orthomvp.cli import main
    from orthomvp.errors import InputError

    build, expect = BAD[case]
    path = build(tmp_path)
    with pytest.raises(InputError, match=expect) as info:
        read_cube_camera(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)
    out = tmp_path / "x.json"
    capsys.readouterr()
    assert main(["isd", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("orthomvp: error: ") and str(path) in err[0]
    assert not out.exists()


@pytest.mark.parametrize(
    "build", [_kaguya, _wac, lambda tmp: _hrsc(tmp)[0]], ids=["tc", "wac", "hrsc"]
)
def test_beyond_the_first_and_last_lines_is_nan(tmp_path: Path, build) -> None:
    """Ground points seen before the first or after the last line (framelet) project to NaN,
    and rays of lines beyond the image are NaN: never extrapolated pixels."""
    path = build(tmp_path)
    camera = read_cube_camera(path)
    samples, lines = cube_isd(path)["image_samples"], cube_isd(path)["image_lines"]
    first, last = camera.image_to_ground(
        np.array([[samples / 2, 0.0], [samples / 2, lines - 1]]), 0.0
    )
    beyond = np.array([first - (last - first) * 0.5, last + (last - first) * 0.5])
    assert np.isnan(camera.project(beyond)[0]).all()
    outside = np.array([[samples / 2, -0.3 * lines], [samples / 2, 1.3 * lines]])
    assert np.isnan(camera.ray(outside)[1]).all()


@pytest.mark.parametrize(
    "build", [_kaguya, _wac, lambda tmp: _hrsc(tmp)[0]], ids=["tc", "wac", "hrsc"]
)
def test_the_isd_written_is_the_cube_camera(tmp_path: Path, build) -> None:
    """`orthomvp isd CUBE -o X.json` of each new model (line scan, push frame, changing line
    rate): the ISD file's camera projects as the cube's own."""
    from orthomvp.camera import read_camera
    from orthomvp.cli import main

    path = build(tmp_path)
    out = tmp_path / "cube.json"
    assert main(["-q", "isd", str(path), "-o", str(out)]) == 0
    cube, written = read_cube_camera(path), read_camera(out)
    samples, lines = cube_isd(path)["image_samples"], cube_isd(path)["image_lines"]
    u, v = np.meshgrid(np.linspace(0, samples - 1, 5), np.linspace(0, lines - 1, 5))
    ground = cube.image_to_ground(np.stack([u.ravel(), v.ravel()], -1), 0.0)
    np.testing.assert_allclose(written.project(ground)[0], cube.project(ground)[0], atol=1e-9)
