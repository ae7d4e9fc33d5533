"""Hostile input to the renderer's readers and to ``scet``: dataset manifests and labels (fuzzed
like the scene loader), EXR headers, flags, backends, full disks, and what ``scet`` answers a
bug with (exit 1, one line, the traceback in a log file)."""

from __future__ import annotations

import argparse
import json
import os
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimator.errors import TrackerInputError
from scet_render.cli import main
from scet_render.dataset import DatasetError, iter_labels, read_exr
from scet_render.dataset.manifest import read_manifest
from scet_render.render import BackendUnavailableError, choose_variant, gpu_available
from scet_render.runner import EXIT_BAD_INPUT, EXIT_INTERNAL, LOG_DIR_ENV, run
from tests.estimator.hostile_json import hostile_text, write_text

ROOT = Path(__file__).resolve().parents[2]
#: Examples per fuzz test (SCET_FUZZ_EXAMPLES=3000 for a long run; each reader passed 3000).
EXAMPLES = settings(max_examples=int(os.environ.get("SCET_FUZZ_EXAMPLES", 150)),
                    deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])

MANIFEST = {"format": "scet-dataset", "version": 1, "frames": 1, "seed": 0,
            "trajectory": "fixations", "scene": {"toml": "", "name": "x"},
            "image": {"width_px": 640, "height_px": 480, "png_bit_depth": 16}}
LABEL = {"frame": 0, "strobe": 3, "time_s": 0.0031, "pulse_start_s": 0.00305, "first_row": 0,
         "last_row": 40, "full_rows": [2, 38], "target_m": [0.01, -0.02, -0.7],
         "yaw_rad": 0.01, "pitch_rad": -0.02, "cornea_center_m": [0.0, 0.0, 0.00425],
         "glints_px": [[100.5, 200.25], None], "glints_visible": [True, False]}


def dataset(folder: Path, manifest=MANIFEST, labels=(LABEL,)) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    (folder / "labels.jsonl").write_text("".join(json.dumps(x) + "\n" for x in labels))
    return folder


# --------------------------------------------------------------------------- manifest, labels


@pytest.mark.parametrize("edit, key, words", [
    ({"frames": 10 ** 400}, "frames", "expected an integer in"),
    ({"frames": [1]}, "frames", "expected an integer, got a list"),
    ({"image": {"width_px": 640, "height_px": 1e9, "png_bit_depth": 16}}, "image.height_px",
     "integer in"),
    ({"scene": []}, "scene", "expected an object, got a list"),
    ({"format": "scet-capture"}, "format", "key 'format' is 'scet-capture'"),
    ({"version": [1]}, "version", "this SCET reads scet-dataset version 1, the file says"),
])
def test_a_bad_manifest_names_the_key(tmp_path, edit, key, words):
    folder = dataset(tmp_path / "d", {**MANIFEST, **edit})
    with pytest.raises(DatasetError, match=words) as info:
        read_manifest(folder)
    assert "manifest.json" in str(info.value) and getattr(info.value, "key", None) == key


@pytest.mark.parametrize("edit, key, words", [
    ({"glints_px": {"0": [1, 2]}}, "glints_px", "expected a list"),
    ({"glints_px": [[1.0, float("nan")], None]}, "glints_px[0][1]", "finite"),
    ({"glints_visible": [True]}, "glints_visible", "1 entries for 2 glints_px"),
    ({"glints_visible": [1, 0]}, "glints_visible[0]", "true or false"),
    ({"yaw_rad": 45.0}, "yaw_rad", "check the unit"),
    ({"target_m": [10, 20, -700]}, "target_m[2]", "check the unit"),
    ({"full_rows": [2]}, "full_rows", "expected 2 integers"),
    ({"frame": 2 ** 80}, "frame", "integer in"),
])
def test_a_bad_label_names_the_line_and_key(tmp_path, edit, key, words):
    folder = dataset(tmp_path / "d", labels=(LABEL, {**LABEL, **edit}))
    with pytest.raises(DatasetError, match=words) as info:
        list(iter_labels(folder))
    assert info.value.path == f"{folder / 'labels.jsonl'}, line 2" and info.value.key == key


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("hostile_dataset")


def only_dataset_errors(read, named):
    try:
        return read()
    except DatasetError as exc:
        assert str(named) in str(exc), exc
        return None


@given(data=st.data())
@EXAMPLES
def test_fuzz_manifest(work, data):
    folder = dataset(work / "m")
    write_text(folder / "manifest.json", hostile_text(data, MANIFEST))
    manifest = only_dataset_errors(lambda: read_manifest(folder), folder / "manifest.json")
    if manifest is not None:
        assert 1 <= manifest["frames"] and manifest["image"]["png_bit_depth"] in (8, 16)


@given(data=st.data())
@EXAMPLES
def test_fuzz_labels(work, data):
    folder = dataset(work / "l")
    write_text(folder / "labels.jsonl", json.dumps(LABEL) + "\n" + hostile_text(data, LABEL))
    labels = only_dataset_errors(lambda: list(iter_labels(folder)), folder / "labels.jsonl")
    for lb in labels or ():
        assert np.isfinite(lb.target_m).all() and lb.glints_px.shape[1] == 2
        assert lb.glints_visible.shape == (lb.glints_px.shape[0],)
        assert math.isfinite(lb.time_s) and abs(lb.yaw_rad) <= math.pi


def test_an_exr_header_claiming_an_enormous_size_is_refused_before_reading(tmp_path):
    OpenEXR = pytest.importorskip("OpenEXR")
    path = tmp_path / "000000.exr"
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "scet_format": "scet-dataset", "scet_version": 1}
    with OpenEXR.File(header, {"Y": np.zeros((4, 4), np.float32)}) as exr:
        exr.write(str(path))
    raw = path.read_bytes()
    at = raw.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    path.write_bytes(raw[:at + 8] + np.array([29999, 29999], "<i4").tobytes() + raw[at + 16:])
    with pytest.raises(DatasetError, match="frame size 30000x30000 px in its EXR header"):
        read_exr(path)
    with pytest.raises(DatasetError, match="the dataset's is 4x4"):
        read_exr(path, (4, 4))


# --------------------------------------------------------------------------- flags, backends


@pytest.mark.parametrize("argv, words", [
    (["export-mitsuba", "--yaw-deg", "nan", "--out", "x"], "--yaw-deg: expected a finite number"),
    (["export-mitsuba", "--pitch-deg", "inf", "--out", "x"], "--pitch-deg: expected a finite"),
    (["simulate", "--noise", "nan", "--out", "x.npz"], "--noise: expected a finite"),
    (["simulate", "--targets", "grid:100000x100000", "--out", "x.npz"],
     "grid:100000x100000'.*got 100000x100000 = 10000000000"),
    (["render", "--frames", "100000000000", "--out", "d"], "--frames: expected an integer in"),
    (["bands", "--frames", "1000000"], "--frames: expected an integer in"),
    (["render", "--spp", "-4", "--frames", "1", "--out", "d"], "--spp: expected an integer in"),
])
def test_absurd_flags_are_refused_up_front(tmp_path, capsys, monkeypatch, argv, words):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == EXIT_BAD_INPUT
    assert __import__("re").search(words, capsys.readouterr().err)
    assert list(tmp_path.iterdir()) == []


def test_a_cuda_variant_without_a_gpu_is_a_clean_error(tmp_path, capsys):
    with pytest.raises(BackendUnavailableError, match="needs an NVIDIA GPU"):
        choose_variant("cuda_ad_rgb", gpu=False)
    if gpu_available():
        pytest.skip("this machine has a GPU: the CLI would render")
    assert main(["render", "--frames", "1", "--variant", "cuda_ad_rgb",
                 "--out", str(tmp_path / "d")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cuda_ad_rgb needs an NVIDIA GPU" in err
    assert not (tmp_path / "d").exists()


# --------------------------------------------------------------------------- outputs


def test_a_full_disk_is_exit_2_naming_the_file_and_leaves_nothing(tmp_path):
    out = tmp_path / "glints.npz"
    script = ("import resource, signal, sys\n"
              "import scet_render.cli, scet_render.simulate, estimator.scene\n"
              "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
              "resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))\n"
              "sys.exit(scet_render.cli.main(['simulate', '--out', sys.argv[1]]))\n")
    proc = subprocess.run([sys.executable, "-c", script, str(out)], capture_output=True, text=True,
                          cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PYTHONDONTWRITEBYTECODE": "1",
                                         "OPENBLAS_NUM_THREADS": "1"}, timeout=300)
    assert proc.returncode == EXIT_BAD_INPUT, proc.stderr
    assert proc.stderr == f"scet simulate: error: {out}: cannot write (File too large)\n"
    assert list(tmp_path.iterdir()) == []


def test_track_refuses_to_write_over_its_calibration(tmp_path, capsys):
    from estimator.calibration import Calibration
    from estimator.folders import save_calibration
    from estimator.scene import load_scene

    cal = save_calibration(Calibration.ground_truth(load_scene()), tmp_path / "cal.json")
    before = cal.read_bytes()
    folder = dataset(tmp_path / "d")
    # The stub manifest's scene does not load: --scene names one (the folder's is warned about).
    assert main(["track", str(folder), "--scene", "paper_sim", "--calibration", str(cal),
                 "--out", str(cal)]) == 2
    assert "is one of the inputs" in capsys.readouterr().err and cal.read_bytes() == before
    assert main(["calibrate", str(folder), "--scene", "paper_sim", "--out",
                 str(folder / "labels.jsonl")]) == 2
    assert "is one of the inputs" in capsys.readouterr().err
    assert (folder / "labels.jsonl").read_text().startswith('{"frame": 0')


# --------------------------------------------------------------------------- bugs do not hide


def probe(func, debug=False):
    return argparse.Namespace(command="probe", func=func, debug=debug)


def test_an_internal_error_is_exit_1_one_line_and_a_log_file(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(LOG_DIR_ENV, str(tmp_path))

    def buggy(args):
        return {}["missing"]

    assert run(probe(buggy)) == EXIT_INTERNAL
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("scet probe: internal error: KeyError: 'missing'")
    (log,) = tmp_path.glob("scet-probe-*.log")
    assert str(log) in err and "Traceback" in log.read_text() and "in buggy" in log.read_text()
    assert run(probe(buggy, debug=True)) == EXIT_INTERNAL
    assert "Traceback" in capsys.readouterr().err


def test_a_value_error_from_numpy_is_a_bug_one_from_scet_is_bad_input(tmp_path, capsys,
                                                                       monkeypatch):
    monkeypatch.setenv(LOG_DIR_ENV, str(tmp_path))
    assert run(probe(lambda a: np.zeros(3) + np.zeros(4))) == EXIT_INTERNAL
    assert "internal error: ValueError" in capsys.readouterr().err
    from estimator.setup import Screen

    screen = Screen((-0.2, 0.2), (-0.1, 0.1), -0.7)
    assert run(probe(lambda a: screen.grid(0, 3))) == EXIT_BAD_INPUT
    assert capsys.readouterr().err == "scet probe: error: grid needs at least 1x1 points, got 0x3\n"
    assert run(probe(lambda a: open(tmp_path / "nowhere" / "x"))) == EXIT_BAD_INPUT
    assert "nowhere/x: No such file or directory" in capsys.readouterr().err
    assert run(probe(lambda a: (_ for _ in ()).throw(TrackerInputError("bad", path="f.json",
                                                                         key="k")))) == 2
    assert capsys.readouterr().err == "scet probe: error: f.json, key 'k': bad\n"


def test_internal_errors_in_frames_make_track_exit_1(tmp_path, capsys, monkeypatch):
    # The log records of the tracker's per-frame internal errors reach the run's log file.
    import logging

    monkeypatch.setenv(LOG_DIR_ENV, str(tmp_path))

    def frames_fail(args):
        try:
            raise ZeroDivisionError("in frame 3")
        except ZeroDivisionError:
            logging.getLogger("estimator.tracker").error("frame 3: internal error", exc_info=True)
        return 0

    assert run(probe(frames_fail)) == 0
    err = capsys.readouterr().err
    (log,) = tmp_path.glob("scet-probe-*.log")
    assert err == f"frame 3: internal error (traceback in {log})\n"
    assert "ZeroDivisionError: in frame 3" in log.read_text()


def test_a_dataset_claiming_frames_it_does_not_hold_is_refused_not_iterated(tmp_path):
    from scet_render.dataset import open_dataset, verify_dataset

    folder = dataset(tmp_path / "d", {**MANIFEST, "frames": 10 ** 8, "scene": {"toml": "", "sha256": ""}})
    (folder / "frames").mkdir()
    with pytest.raises(DatasetError, match="key 'frames': claims 100000000 frames, .* holds 0"):
        open_dataset(folder)
    assert len(verify_dataset(folder)) == 1 and "claims 100000000 frames" in verify_dataset(folder)[0]
