"""`scet camera calibrate` and the `--camera` option of `scet calibrate`, `scet track`,
`scet run` and `scet compare`: a camera.json from synthetic board views
(tests/estimator/board_images.py), and every refusal one line with exit status 2 naming the
file (and key)."""

import json

import pytest

from estimator.lens import DEFAULT_BOARD, BoardSpec, read_camera_file, write_board
from scet_render.cli import main
from tests.estimator.board_images import TRUE_K, write_views


@pytest.fixture(scope="module")
def views(tmp_path_factory):
    folder = tmp_path_factory.mktemp("views")
    write_views(folder, DEFAULT_BOARD, 5, seed=4)
    return folder


def _one_line_error(capsys, *words):
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err
    return err


def test_calibrate_writes_a_camera_file(views, tmp_path, capsys):
    out = tmp_path / "camera.json"
    assert main(["camera", "calibrate", str(views), "--out", str(out), "--min-views", "4"]) == 0
    text = capsys.readouterr().out
    assert f"camera written to {out}" in text and text.count("corners, RMS") == 5
    cam = read_camera_file(out)
    assert abs(cam.fx_px / TRUE_K[0, 0] - 1) < 0.01  # 5 views: looser than the 12-view test
    doc = json.loads(out.read_text())
    assert doc["board"]["squares_x"] == 11 and doc["distortion_model"] == "opencv5"
    assert len(doc["views"]) == 5 and all(v["rms_px"] < 0.2 for v in doc["views"])


def test_too_few_views_and_no_board_are_one_line(views, tmp_path, capsys):
    out = tmp_path / "camera.json"
    assert main(["camera", "calibrate", str(views), "--out", str(out)]) == 2
    _one_line_error(capsys, str(views), "5 usable board views", "at least 8")
    other = tmp_path / "board.json"
    write_board(BoardSpec(11, 8, 2.5, 1.8, "DICT_6X6_50"), other)
    assert main(["camera", "calibrate", str(views), "--out", str(out), "--board", str(other)]) == 2
    _one_line_error(capsys, "no board corners found")
    assert main(["camera", "calibrate", str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    _one_line_error(capsys, "nowhere", "not a folder")
    assert not out.exists()


def test_a_bad_board_file_names_its_key(views, tmp_path, capsys):
    board = tmp_path / "board.json"
    write_board(DEFAULT_BOARD, board)
    doc = json.loads(board.read_text())
    board.write_text(json.dumps({**doc, "square_mm": "2.5"}))
    assert main(["camera", "calibrate", str(views), "--out", str(tmp_path / "c.json"),
                 "--board", str(board)]) == 2
    _one_line_error(capsys, str(board), "square_mm")


def test_the_camera_option_checks_the_file(tmp_path, capsys):
    K = [[643.0, 0.0, 400.0], [0.0, 643.0, 300.0], [0.0, 0.0, 1.0]]
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps({"format": "scet-camera", "version": 1,
                               "image_size_px": [800, 600], "K": K,
                               "distortion": [-0.1, 0.05, 0.0, 0.0, 0.0]}))
    folder = tmp_path / "frames"
    folder.mkdir()
    for cmd in (["track", str(folder), "--scene", "paper_sim", "--calibration", "x.json",
                 "--out", str(tmp_path / "s.csv")],
                ["calibrate", str(folder), "--scene", "paper_sim", "--out",
                 str(tmp_path / "cal.json")],
                ["run", "--scene", "paper_sim", "--out", str(tmp_path / "cap"), "--calibration",
                 "x.json", "--samples", str(tmp_path / "s.csv"), "--replay", str(folder)],
                ["compare", str(folder), "--scene", "paper_sim", "--report-dir",
                 str(tmp_path / "rep")]):
        assert main([*cmd, "--camera", str(cam)]) == 2
        _one_line_error(capsys, str(cam), "image_size_px", "800x600", "640x480")
    cam.write_text('{"format": "scet-camera", "version": 1, "K": [[1, 0], NaN]')
    assert main(["track", str(folder), "--scene", "paper_sim", "--calibration", "x.json",
                 "--out", str(tmp_path / "s.csv"), "--camera", str(cam)]) == 2
    _one_line_error(capsys, str(cam))


def test_a_calibration_records_its_camera_file_and_track_holds_to_it(tmp_path, capsys):
    """scet calibrate --camera writes the camera file's path and SHA-256 into the calibration;
    scet track refuses another camera file (or none) in one line naming the calibration and
    its key, takes the same bytes under another name, and warns when the calibration has no
    record."""
    import numpy as np

    from estimator.folders import load_calibration
    from estimator.lens import camera_file_record
    from estimator.scene import load_scene
    from tests.estimator.test_camera_file_tracker import DIST, _calibration_folder

    def camera(path, d):
        path.write_text(json.dumps({"format": "scet-camera", "version": 1,
                                    "image_size_px": [640, 480], "K": setup.camera.K.tolist(),
                                    "distortion": list(d)}))
        return path

    setup = load_scene("paper_sim")
    lens = camera(tmp_path / "lens.json", DIST)
    other = camera(tmp_path / "other.json", DIST * np.array([1.1, 1, 1, 1, 1]))
    copy = tmp_path / "copy.json"
    copy.write_bytes(lens.read_bytes())
    folder = _calibration_folder(tmp_path / "cal", setup, setup.camera,
                                 setup.screen.grid(3, 3, margin=0.0))
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(folder), "--scene", "paper_sim", "--camera", str(lens),
                 "--out", str(cal)]) == 0
    assert load_calibration(cal).camera_file == camera_file_record(lens)
    capsys.readouterr()
    track = ["track", str(folder), "--scene", "paper_sim", "--calibration", str(cal)]
    assert main([*track, "--out", str(tmp_path / "a.csv"), "--camera", str(other)]) == 2
    _one_line_error(capsys, str(cal), "camera_file.sha256", str(other), "lens.json")
    assert main([*track, "--out", str(tmp_path / "b.csv")]) == 2
    _one_line_error(capsys, str(cal), "'camera_file'", "--camera")
    assert main([*track, "--out", str(tmp_path / "c.csv"), "--camera", str(copy)]) == 0
    assert "warning" not in capsys.readouterr().err
    plain = tmp_path / "plain.json"
    assert main(["calibrate", str(folder), "--scene", "paper_sim", "--out", str(plain)]) == 0
    assert load_calibration(plain).camera_file is None
    capsys.readouterr()
    assert main(["track", str(folder), "--scene", "paper_sim", "--calibration", str(plain),
                 "--out", str(tmp_path / "d.csv"), "--camera", str(lens)]) == 0
    assert "records no camera file" in capsys.readouterr().err


def test_scet_run_holds_to_the_calibrations_camera_file(tmp_path, capsys):
    """scet run refuses, before opening any camera, a camera file other than the one its
    calibration was made with."""
    from estimator.calibration import Calibration
    from estimator.lens import camera_file_record
    from estimator.scene import load_scene

    def camera(path, k1):
        path.write_text(json.dumps({"format": "scet-camera", "version": 1,
                                    "image_size_px": [640, 480],
                                    "K": [[1300.0, 0, 319.5], [0, 1300.0, 239.5], [0, 0, 1]],
                                    "distortion": [k1, 0.0, 0.0, 0.0, 0.0]}))
        return path

    cal = tmp_path / "cal.json"
    rec = camera_file_record(camera(tmp_path / "a.json", -0.1))
    cal.write_text(Calibration.ground_truth(load_scene("paper_sim"), camera_file=rec).to_json())
    folder = tmp_path / "frames"
    folder.mkdir()
    assert main(["run", "--scene", "paper_sim", "--out", str(tmp_path / "cap"), "--calibration",
                 str(cal), "--method", "geometric", "--samples", str(tmp_path / "s.csv"),
                 "--replay", str(folder), "--camera", str(camera(tmp_path / "b.json", -0.2))]) == 2
    _one_line_error(capsys, str(cal), "camera_file.sha256", "b.json")
    assert not (tmp_path / "cap").exists()
