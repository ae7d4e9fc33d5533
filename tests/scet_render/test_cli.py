"""The ``scet`` command line, run in-process."""

import numpy as np
import pytest

from scet_render.cli import main
from scet_render.simulate import load_observations


def test_scenes_and_scene(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    for name in ("paper_sim", "paper_sim_doubled", "lighting_grid", "prototype_ov5647"):
        assert name in out
    assert main(["scene", "prototype_ov5647"]) == 0
    assert "S = 786, N = 480" in capsys.readouterr().out


def test_bands_table_and_png(capsys, tmp_path):
    png = tmp_path / "bands.png"
    assert main(["bands", "prototype_ov5647", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # 16 pulses of frame 0 plus the one from the previous frame that lights the top rows.
    table = [line for line in out.splitlines()
             if len(line.split()) == 9 and line.split()[0].lstrip("-").isdigit()]
    assert len(table) == 17
    assert "visible share 9.77" in out


def test_simulate_writes_documented_file(capsys, tmp_path):
    out = tmp_path / "g.npz"
    assert main(["simulate", "paper_sim", "--targets", "grid:24x15", "--noise", "0.5",
                 "--seed", "1", "--out", str(out)]) == 0
    obs, meta = load_observations(out)
    assert obs.glints_px.shape == (360, 40, 2) and meta["noise_px"] == 0.5
    assert main(["simulate", "paper_sim", "--seed", "1", "--out", str(tmp_path / "h.npz")]) == 0
    again, _ = load_observations(tmp_path / "h.npz")
    assert np.array_equal(obs.glints_px, again.glints_px, equal_nan=True)


def test_errors_exit_2_with_one_line(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('format = "scet-scene"\nversion = 1\n')
    assert main(["bands", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "missing required key" in err
    assert main(["simulate", "--targets", "grid:0x0", "--out", str(tmp_path / "x.npz")]) == 2
    assert not (tmp_path / "x.npz").exists()


def test_demo_runs_on_default_scene(capsys, tmp_path):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "scene paper_sim" in out and "visible glints per target" in out
    assert (tmp_path / "bands.png").exists() and (tmp_path / "glints.npz").exists()


def test_export_mitsuba_writes_a_scene_mitsuba_loads(capsys, tmp_path):
    mi = pytest.importorskip("mitsuba")
    from scet_render.render import activate

    activate()
    assert main(["export-mitsuba", "paper_sim", "--out", str(tmp_path), "--yaw-deg", "5", "--spp", "4"]) == 0
    xml = tmp_path / "scene.xml"
    assert xml.exists()
    scene = mi.load_file(str(xml))
    assert list(scene.sensors()[0].film().size()) == [640, 480]


def test_render_rejects_bad_arguments_before_rendering(capsys, tmp_path):
    assert main(["render", "paper_sim", "--frames", "0", "--out", str(tmp_path / "d")]) == 2
    assert "frames" in capsys.readouterr().err


def test_track_and_calibrate_name_missing_inputs(capsys, tmp_path):
    assert main(["track", str(tmp_path / "nowhere"), "--scene", "paper_sim", "--calibration",
                 str(tmp_path / "cal.json"), "--out", str(tmp_path / "s.csv")]) == 2
    assert "cal.json" in capsys.readouterr().err
    # Without --scene the folder must say its scene: a missing folder is named first.
    assert main(["track", str(tmp_path / "nowhere"), "--calibration", str(tmp_path / "cal.json"),
                 "--out", str(tmp_path / "s.csv")]) == 2
    assert "nowhere: no such folder" in capsys.readouterr().err
    assert main(["calibrate", str(tmp_path / "nowhere"), "--out", str(tmp_path / "cal.json")]) == 2
    assert "nowhere" in capsys.readouterr().err
    assert not (tmp_path / "s.csv").exists() and not (tmp_path / "cal.json").exists()


def test_track_refuses_to_flag_cut_glints_without_glint_flux(capsys, tmp_path):
    from estimator.folders import save_calibration
    from estimator.scene import load_scene
    from tests.estimator.simulated import ground_truth_calibration
    from tests.estimator.test_tracker import draw_frame, write_folder

    setup = load_scene("paper_sim")
    rng = np.random.default_rng(1)
    folder = write_folder(tmp_path / "run", setup, [draw_frame(setup, 0, 0.0, 0.0, rng)])
    save_calibration(ground_truth_calibration(setup), tmp_path / "old.json")  # no glint_flux
    assert main(["track", str(folder), "--scene", "paper_sim", "--calibration",
                 str(tmp_path / "old.json"), "--out", str(tmp_path / "s.csv"),
                 "--flag-cut-glints"]) == 2
    err = capsys.readouterr().err
    assert "old.json" in err and "no glint_flux" in err  # the file and the key
    assert not (tmp_path / "s.csv").exists()
    # Without the option the flag is on only where the calibration can flag: this one tracks.
    for extra in ([], ["--no-flag-cut-glints"]):
        assert main(["track", str(folder), "--scene", "paper_sim", "--calibration",
                     str(tmp_path / "old.json"), "--out", str(tmp_path / "s.csv")] + extra) == 0
        assert (tmp_path / "s.csv").exists()
