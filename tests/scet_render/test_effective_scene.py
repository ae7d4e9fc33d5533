"""Datasets that describe themselves: the manifest's ``scene.toml`` is the effective scene (the
text that loads into exactly the setup rendered, after every override in code), and
``scet calibrate / track / compare / score`` take the folder's scene when ``--scene`` is not
given, say which they used, and warn when ``--scene`` disagrees. No rendering: the manifest is
prepared and committed as the writer does before its first frame."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from estimator.banding import calibration_setup, scaled_setup, strobe_setup
from estimator.errors import SceneError
from estimator.scene import builtin_scenes, load_scene, parse_scene
from scet_render.cli import main
from scet_render.cli_scene import recorded_scene
from scet_render.dataset import commit_manifest, prepare_dataset
from scet_render.dataset.effective import effective_scene_text, setup_differences


def _text(setup) -> str:
    return Path(setup.source).read_text(encoding="utf-8")


@pytest.mark.parametrize("name", builtin_scenes())
@pytest.mark.parametrize("derive", ["scaled", "strobe", "calibration", "all"])
def test_the_effective_text_loads_into_the_very_setup(name, derive):
    base = load_scene(name)
    small = scaled_setup(base, 2) if base.sensor.total_lines % 2 == 0 else base
    setup = {"scaled": small, "strobe": strobe_setup(base, 8),
             "calibration": calibration_setup(base),
             "all": calibration_setup(strobe_setup(small, 8))}[derive]
    text, overridden, differs = effective_scene_text(setup, _text(base))
    back = parse_scene(text)
    assert setup_differences(back, setup) == [] == differs  # every field, bit for bit
    assert overridden == setup_differences(base, setup) != []
    # Only the overridden keys are rewritten; the file's comments stay.
    assert text.count("# overridden") >= len(overridden)
    assert "# World frame" in text or "#" in _text(base).splitlines()[0]


def test_an_unchanged_setup_records_the_file_itself():
    setup = load_scene("paper_sim")
    assert effective_scene_text(setup, _text(setup)) == (_text(setup), [], [])


def test_what_a_scene_file_cannot_say_is_on_record(tmp_path, capsys):
    # A camera moved in code: the rewrite carries intrinsics and timing, not a pose.
    setup = scaled_setup(load_scene("paper_sim"), 2)
    moved = dataclasses.replace(setup, camera=dataclasses.replace(
        setup.camera, position_m=setup.camera.position_m + 1e-3))
    text, overridden, differs = effective_scene_text(moved, _text(setup))
    assert overridden == ["sensor"] and differs == ["camera"]
    folder = _dataset(tmp_path / "d", moved, _text(setup))
    assert json.loads((folder / "manifest.json").read_text())["scene"]["differs"] == ["camera"]
    assert recorded_scene(folder)[2] == ["camera"]
    assert main(["track", str(folder), "--calibration", str(tmp_path / "none.json"),
                 "--out", str(tmp_path / "s.csv")]) == 2
    err = capsys.readouterr().err
    assert "says the frames were rendered with another camera than it records" in err


def _dataset(folder: Path, setup, text) -> Path:
    plan = prepare_dataset(setup, folder, frames=2, spp=1, scene_text=text)
    commit_manifest(plan, "scalar_rgb", {})
    return folder


def test_the_quick_validations_dataset_records_its_320x240_scene(tmp_path):
    # scet validate --quick: paper_sim at half size, 16 pulses (issue 33's first snag).
    base = load_scene("paper_sim")
    setup = strobe_setup(scaled_setup(base, 2), 8)
    folder = _dataset(tmp_path / "test_p8", setup, _text(base))
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["scene"]["overridden"] == ["camera", "sensor", "strobe"]
    assert "resolution_px = [320, 240]  # overridden" in manifest["scene"]["toml"]
    recorded, place, differs = recorded_scene(folder)
    assert place.endswith("manifest.json (its scene.toml)") and differs == []
    assert setup_differences(recorded, setup) == []


def test_track_takes_the_folders_scene_and_warns_on_another(tmp_path, capsys):
    base = load_scene("paper_sim")
    folder = _dataset(tmp_path / "d", scaled_setup(base, 2), _text(base))
    args = ["track", str(folder), "--calibration", str(tmp_path / "none.json"),
            "--out", str(tmp_path / "s.csv")]
    assert main(args) == 2  # the calibration is missing: refused after the scene is chosen
    out, err = capsys.readouterr()
    assert f"scene: paper_sim, from {folder}/manifest.json (its scene.toml)" in out
    assert "warning" not in err and "none.json" in err
    assert main(args + ["--scene", "paper_sim"]) == 2
    out, err = capsys.readouterr()
    assert "scene: paper_sim, from --scene paper_sim" in out
    assert (f"scet track: warning: --scene paper_sim differs from the scene in {folder}/"
            "manifest.json (its scene.toml) (camera, sensor)") in err


def test_a_recorded_scene_that_does_not_parse_is_one_line_naming_the_file(tmp_path, capsys):
    base = load_scene("paper_sim")
    folder = _dataset(tmp_path / "d", base, _text(base))
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["scene"]["toml"] = manifest["scene"]["toml"].replace("focal_px = 1300.0",
                                                                  "focal_px = -3")
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(SceneError):
        recorded_scene(folder)
    for cmd in (["calibrate", str(folder), "--out", str(tmp_path / "c.json")],
                ["track", str(folder), "--calibration", str(tmp_path / "c.json"), "--out",
                 str(tmp_path / "s.csv")],
                ["score", str(tmp_path / "s.csv"), str(folder)],
                ["compare", str(folder), "--report-dir", str(tmp_path / "r")]):
        assert main(cmd) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "manifest.json (its scene.toml)" in err[0]
        assert "camera" in err[0] and "focal_px" in err[0]


def test_a_folder_that_records_no_scene_needs_scene(tmp_path, capsys):
    folder = tmp_path / "frames"
    (folder / "frames").mkdir(parents=True)
    for cmd in (["calibrate", str(folder), "--out", str(tmp_path / "c.json")],
                ["track", str(folder), "--calibration", str(tmp_path / "c.json"), "--out",
                 str(tmp_path / "s.csv")],
                ["compare", str(folder), "--report-dir", str(tmp_path / "r")]):
        assert main(cmd) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{folder}: records no scene" in err[0] and "--scene" in err[0]
    # A capture header may carry the scene (scet-capture, optional key 'scene').
    (folder / "capture.json").write_text(json.dumps({"scene": {"toml": _text(load_scene())}}))
    setup, place, _ = recorded_scene(folder)
    assert setup.name == "paper_sim" and place.endswith("capture.json (its scene.toml)")
    (folder / "capture.json").write_text(json.dumps({"scene": {"toml": 3}}))
    assert main(["track", str(folder), "--calibration", str(tmp_path / "c.json"), "--out",
                 str(tmp_path / "s.csv")]) == 2
    assert "capture.json: key 'scene.toml' must be" in capsys.readouterr().err
