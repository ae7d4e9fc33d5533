"""Which camera file a calibration was made with (issue 30): the calibration file records its
path and SHA-256, reads it back, and a tracker run through another camera file (or none) is
refused naming the calibration file and key; one made without a camera file only warns."""

import json

import pytest

from estimator.calibration import Calibration
from estimator.lens import CameraFileError, camera_file_record, check_camera_record


def _camera(path, k1):
    path.write_text(json.dumps({"format": "scet-camera", "version": 1,
                                "image_size_px": [640, 480],
                                "K": [[1300.0, 0.0, 319.5], [0.0, 1300.0, 239.5], [0, 0, 1]],
                                "distortion": [k1, 0.0, 0.0, 0.0, 0.0]}))
    return path


def test_the_record_names_the_file_and_its_content(tmp_path):
    a = _camera(tmp_path / "a.json", -0.1)
    rec = camera_file_record(a)
    assert rec["path"] == str(a.resolve()) and len(rec["sha256"]) == 64
    # the same bytes elsewhere are the same camera; one coefficient changed is not
    b = tmp_path / "sub" / "copy.json"
    b.parent.mkdir()
    b.write_bytes(a.read_bytes())
    assert camera_file_record(b)["sha256"] == rec["sha256"]
    assert camera_file_record(_camera(tmp_path / "c.json", -0.11))["sha256"] != rec["sha256"]


def test_a_calibration_keeps_its_record_through_its_file(tmp_path):
    rec = camera_file_record(_camera(tmp_path / "a.json", -0.1))
    cal = Calibration(camera_file=rec)
    back = Calibration.from_json(cal.to_json())
    assert back.camera_file == rec
    assert "camera_file" not in Calibration().to_dict()  # files without a camera as before
    bad = json.loads(cal.to_json())
    bad["camera_file"]["sha256"] = "xyz"
    with pytest.raises(ValueError, match="camera_file.sha256"):
        Calibration.from_dict(bad, path="cal.json")


def test_another_camera_file_is_refused_the_same_one_is_not(tmp_path):
    a = _camera(tmp_path / "a.json", -0.1)
    rec = camera_file_record(a)
    copy = tmp_path / "copy.json"
    copy.write_bytes(a.read_bytes())
    assert check_camera_record(rec, a, "cal.json") is None
    assert check_camera_record(rec, copy, "cal.json") is None
    with pytest.raises(CameraFileError, match=r"cal\.json, key 'camera_file.sha256'.*b\.json"):
        check_camera_record(rec, _camera(tmp_path / "b.json", -0.2), "cal.json")
    with pytest.raises(CameraFileError, match=r"cal\.json, key 'camera_file'.*--camera"):
        check_camera_record(rec, None, "cal.json")


def test_a_calibration_without_a_record_warns_with_a_camera_file(tmp_path):
    assert check_camera_record(None, None, "cal.json") is None
    w = check_camera_record(None, _camera(tmp_path / "a.json", -0.1), "cal.json")
    assert "cal.json records no camera file" in w and "a.json" in w


def test_an_unreadable_camera_file_names_it(tmp_path):
    with pytest.raises(CameraFileError, match="nowhere.json"):
        camera_file_record(tmp_path / "nowhere.json")
