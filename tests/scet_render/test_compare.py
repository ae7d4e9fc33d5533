"""`scet compare` (issue 13, parts 3 and 4): foreign captures, renders of a perturbed scene
the comparison is not told about (tests/scet_render/foreign.py), must each be found and
quantified; the unperturbed capture must pass every row; bad input is a clear error."""

import json
import math

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytest.importorskip("scet_hardware")

from estimator.scene import load_scene  # noqa: E402
from scet_render.cli import main  # noqa: E402
from scet_render.compare import CompareError, compare_capture  # noqa: E402

from .foreign import blurred_capture, foreign_capture, small_scene  # noqa: E402

SPP, CORNEA = 4, "conductor"


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    d = tmp_path_factory.mktemp("compare")
    scene = small_scene(d)
    return d, scene, load_scene(scene)


@pytest.fixture(scope="module")
def results(world):
    d, scene, setup = world
    out = {}

    def get(kind):
        if kind not in out:
            cap = foreign_capture(d, scene, kind)
            out[kind] = compare_capture(cap, setup, frames=4, spp=SPP, cornea=CORNEA, seed=5)
        return out[kind]

    return get


def row_of(result, prefix: str):
    """The verdict row whose quantity starts with ``prefix``."""
    return next(x for x in result.rows if x.quantity.startswith(prefix))


def flagged(result):
    return {r.quantity.split(",")[0].split(" (")[0]: r for r in result.flagged}


def test_an_unperturbed_capture_passes_every_row(results):
    r = results("nominal")
    assert r.flagged == [], [(x.quantity, x.difference, x.tolerance) for x in r.flagged]
    assert len(r.rows) >= 20


#: The blur of issue 30's measurement (px) and how well the comparison must measure it: the
#: bisection's steps are 0.006 px; 1.21 px measured on this 320x240 capture.
BLUR_PX, BLUR_TOL_PX = 1.2, 0.15


def test_a_blurred_capture_is_blamed_on_the_optics(results, world):
    # Every frame of the unperturbed capture blurred by 1.2 px: the timing fit measured it
    # (it refused every frame before: 'the band model leaves 0.091 of a 0.093 modulation'),
    # the blur row measures the blur, and every flagged row is the optics' (the blur moves
    # the pulse, the phase, the glints' peak, energy and area, the noise and the clutter,
    # which were blamed on timing, the sensor and the material).
    d, scene, setup = world
    results("nominal")  # its render is the blurred capture's source
    cap = blurred_capture(d, scene, BLUR_PX)
    r = compare_capture(cap, setup, frames=4, spp=SPP, cornea=CORNEA, seed=5)
    blur = row_of(r, "glint spot size")
    assert not blur.passed and blur.cause == "optics"
    assert abs(r.findings["extra_blur_px"] - BLUR_PX) < BLUR_TOL_PX
    causes = {x.quantity: x.cause for x in r.flagged}
    assert set(causes.values()) == {"optics"}, causes
    assert {"pulse (us)", "strobe phase (us)"} <= set(causes), "the blur moves the band fit"
    assert all("blamed on the optics" in x.note for x in r.flagged if x is not blur)
    # the timing is measured through the blur: S within its tolerance
    assert row_of(r, "S,").passed


def test_another_S_is_found_and_measured(results):
    r = results("S")
    # the capture is made with S = 262 (the scene says 393): within half a line
    assert abs(r.findings["total_lines"] - 262) < 0.5
    row = row_of(r, "S,")
    assert not row.passed and row.cause == "timing"


def test_a_strobe_phase_is_found_and_measured(results, world):
    r = results("phase")
    line_s = world[2].sensor.frame_period_s / world[2].sensor.total_lines
    # 200 us of phase the scene does not have: within a quarter line (10.6 us)
    assert abs(r.findings["phase_diff_s"] - 200e-6) < 0.25 * line_s
    row = row_of(r, "strobe phase")
    assert not row.passed and row.cause == "timing"


def test_an_exposure_one_line_short_is_found_and_measured(results):
    r = results("exposure")
    # one line shorter: -1 line, measured to a quarter line (the unperturbed bias is +0.09)
    assert abs(r.findings["exposure_diff_lines"] + 1.0) < 0.25
    row = row_of(r, "exposure")
    assert not row.passed and row.cause == "timing"


def test_a_20_percent_gain_error_is_found_and_measured(results):
    r = results("gain")
    # the response over the scene's sensor model: 1.2, to 2 % (unperturbed: 0.997-1.002)
    assert abs(r.findings["response_ratio"] - 1.2) < 0.02
    row = row_of(r, "response")
    assert not row.passed and row.cause == "sensor"
    # the render made with the estimated gain matches the capture's glint energies again
    assert row_of(r, "glint energy").passed


def test_lights_off_their_places_are_found_and_measured(results):
    r = results("lights")
    nominal = results("nominal")
    # 0.3 mm per light moves glints ~0.5-1 px at 320x240: the per-light systematic offsets
    # grow from ~0.1 px (noise) to over 0.5 px
    assert r.findings["light_offset_rms_px"] > 0.5
    assert r.findings["light_offset_rms_px"] > 4 * nominal.findings["light_offset_rms_px"]
    row = row_of(r, "per-light")
    assert not row.passed and row.cause == "geometry"


def test_another_corneal_radius_is_found_and_measured(results):
    r = results("radius")
    # the capture's cornea is 7.6 mm (the scene's 7.8): the orbit fit within 0.05 mm (its
    # SE is ~0.01 mm; the offset's scaling with r_c is the model's, so no bias is expected)
    assert abs(r.findings["cornea_radius_mm"] - 7.6) < 0.05
    row = row_of(r, "corneal radius")
    assert not row.passed and row.cause == "geometry"


@pytest.mark.slow
def test_the_default_cornea_at_16_spp_passes_unperturbed_and_finds_the_gain(world, tmp_path):
    # The product's settings (dielectric cornea, 16 spp), 6 frames, ~12 s a capture here:
    # measured, the unperturbed capture passes every row (glints 0.14 px apart, response
    # 0.994) and a 20 % gain error reads 1.193; 1.179 since the iris is lit through the cornea
    # (MNEE's per-pixel Monte Carlo noise on the iris dilutes the fitted response: 0.03).
    d, scene, setup = world
    out = {}
    for kind in ("nominal", "gain"):
        cap = foreign_capture(tmp_path, scene, kind, frames=6, spp=16, cornea="dielectric")
        out[kind] = compare_capture(cap, setup, frames=6, spp=16, cornea="dielectric", seed=5)
    assert out["nominal"].flagged == []
    assert abs(out["gain"].findings["response_ratio"] - 1.2) < 0.03
    # Every flagged row blames the sensor (with the lit iris a second sensor row, beside the
    # response, is flagged too).
    causes = [r.cause for r in out["gain"].flagged]
    assert causes and set(causes) == {"sensor"}


def test_cli_writes_report_and_json(results, world, tmp_path, capsys):
    d, scene, _ = world
    results("nominal")
    rep, js = tmp_path / "rep", tmp_path / "c.json"
    code = main(["compare", str(d / "nominal-capture"), "--scene", str(scene), "--frames", "3",
                 "--spp", "4", "--cornea", "conductor", "--report-dir", str(rep), "--json",
                 str(js)])
    assert code == 0
    text = (rep / "compare.md").read_text()
    assert "| verdict |" in text and "reason of the tolerance" in text
    assert (rep / "compare" / "pair.png").is_file() and (rep / "compare" / "profiles.png").is_file()
    doc = json.loads(js.read_text())
    assert doc["format"] == "scet-compare" and doc["frames"] == [0, 1, 2]
    assert "quantities compared" in capsys.readouterr().out


def _one_line_error(capsys, argv):
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "Traceback" not in err[0]
    return err[0]


def test_too_few_frames_for_the_drift_is_a_flagged_row(world, tmp_path):
    d, scene, setup = world
    cap = foreign_capture(tmp_path, scene, "nominal", frames=2)
    r = compare_capture(cap, setup, frames=2, spp=SPP, cornea=CORNEA)
    row = row_of(r, "banded frames")
    assert not row.passed and "nominal strobe clock" in row.note
    assert math.isnan(r.findings["clock_ppm"])


def _rewrite_frames(cap, fn):
    from estimator.capture import CaptureFolder
    from estimator.capture.raw import encode_raw

    c = CaptureFolder(cap)
    for _, d, _, _ in c.index.values():
        path = cap / d["file"]
        mosaic = c.read_raw(d["file"], "test")
        path.write_bytes(encode_raw(fn(mosaic), c.raw_format, c.stride).tobytes())


def test_dark_and_saturated_captures_are_clear_errors(world, tmp_path, capsys):
    d, scene, _ = world
    results_dir = tmp_path
    for kind, fn in (("dark", lambda m: np.full_like(m, 16)),
                     ("saturated", lambda m: np.full_like(m, 1023))):
        cap = foreign_capture(results_dir / kind, scene, "nominal", frames=3)
        _rewrite_frames(cap, fn)
        line = _one_line_error(capsys, ["compare", str(cap), "--scene", str(scene),
                                        "--report-dir", str(tmp_path / "r")])
        assert kind in line and "no frame with bands" in line


def test_a_scene_of_another_resolution_is_a_clear_error(world, capsys, tmp_path):
    d, scene, _ = world
    cap = foreign_capture(tmp_path, scene, "nominal", frames=1)
    code = main(["compare", str(cap), "--scene", "paper_sim", "--report-dir",
                 str(tmp_path / "r")])
    err = capsys.readouterr().err.strip().splitlines()
    # The replayed capture records its scene: a warning that --scene differs from it, then
    # the one-line error.
    assert code == 2 and len(err) == 2 and not any("Traceback" in e for e in err)
    assert "--scene paper_sim differs from the scene in" in err[0]
    assert "320x240" in err[1] and "640x480" in err[1]


def test_a_missing_capture_is_a_clear_error(capsys, tmp_path):
    line = _one_line_error(capsys, ["compare", str(tmp_path / "nothing"), "--report-dir",
                                    str(tmp_path / "r")])
    assert f"{tmp_path / 'nothing'}: no such folder" in line
    # Named with --scene, the capture reader names what is missing.
    line = _one_line_error(capsys, ["compare", str(tmp_path / "nothing"), "--scene", "paper_sim",
                                    "--report-dir", str(tmp_path / "r")])
    assert "capture.json" in line


def test_compare_error_is_an_input_error():
    from estimator.errors import InputError

    assert issubclass(CompareError, InputError)


def test_a_calibration_file_is_used_and_checked(results, world, tmp_path, capsys):
    from dataclasses import replace

    from estimator.folders import save_calibration
    from scet_render.compare import nominal_calibration

    d, scene, setup = world
    results("nominal")
    cal = save_calibration(nominal_calibration(setup), tmp_path / "cal.json")
    args = ["compare", str(d / "nominal-capture"), "--scene", str(scene), "--frames", "3",
            "--spp", "4", "--cornea", "conductor", "--report-dir", str(tmp_path / "r")]
    assert main(args + ["--calibration", str(cal)]) == 0
    assert "0 flagged" in capsys.readouterr().out
    # polynomial gaze without a mapping, geometric without an orbit: one line each, exit 2
    line = _one_line_error(capsys, args + ["--calibration", str(cal), "--method", "polynomial"])
    assert "no Eq. (1) gaze mapping" in line
    bare = save_calibration(replace(nominal_calibration(setup), orbit_radius_m=float("nan")),
                            tmp_path / "bare.json")
    line = _one_line_error(capsys, args + ["--calibration", str(bare)])
    assert "orbit" in line


def test_a_scene_with_another_bit_depth_is_a_clear_error(world, tmp_path, capsys):
    d, scene, _ = world
    cap = foreign_capture(tmp_path, scene, "nominal", frames=1)
    head = cap / "capture.json"
    doc = json.loads(head.read_text())
    doc["camera"]["sensor_mode"]["bit_depth"] = 8
    head.write_text(json.dumps(doc))
    line = _one_line_error(capsys, ["compare", str(cap), "--scene", str(scene),
                                    "--report-dir", str(tmp_path / "r")])
    assert "bit_depth" in line and "10-bit" in line


@pytest.mark.slow
def test_a_capture_through_a_lens_is_compared_with_its_camera_file(world, tmp_path):
    # A capture rendered through a barrel lens (k1 = -0.5: the 320x240 frame's corners move
    # 11 px, its glints 0.5-1.8 px) and replayed with the pinhole scene's header: compared
    # with --camera (the lens's camera file) its detections are undistorted and its render is
    # made through the same lens, and every row passes.
    from dataclasses import replace

    from scet_hardware.capture import replay_dataset
    from scet_render.dataset import render_dataset

    d, scene, setup = world
    k = [-0.5, 0.0, 0.0, 0.0, 0.0]
    lens = replace(setup, camera=replace(setup.camera, distortion=np.array(k)))
    render_dataset(lens, tmp_path / "ds", frames=4, spp=SPP, cornea=CORNEA, seed=3,
                   scene_text=scene.read_text(encoding="utf-8"))
    cap = replay_dataset(tmp_path / "ds", tmp_path / "cap", scene=scene)
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps({"format": "scet-camera", "version": 1,
                               "image_size_px": [320, 240], "K": setup.camera.K.tolist(),
                               "distortion": k}))
    js = tmp_path / "c.json"
    assert main(["compare", str(cap), "--scene", str(scene), "--camera", str(cam), "--frames",
                 "4", "--spp", str(SPP), "--cornea", CORNEA, "--seed", "5", "--report-dir",
                 str(tmp_path / "rep"), "--json", str(js)]) == 0
    doc = json.loads(js.read_text())
    assert doc["flagged"] == 0, [r for r in doc["rows"] if not r["passed"]]
