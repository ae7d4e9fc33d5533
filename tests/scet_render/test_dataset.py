"""Rendered datasets: layout, file contents, labels against the banding model, resume, refusal.

Tests that render use the real Mitsuba renderer (``scet_render.render.rolling_shutter``) on a
half-resolution copy of the paper's setup (320 x 240, S = 393 lines: the same line time
fraction, so the bands keep their timing) at 2 spp; they skip themselves when the renderer or
Mitsuba is missing.
"""

import hashlib
import json
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from estimator.banding import row_pulse_weights, strobe_instant
from estimator.geometry import Camera
from estimator.scene import load_scene, parse_scene
from scet_render.dataset.effective import setup_differences
from scet_render.dataset import (
    FORMAT,
    LABELS_NAME,
    TRAJECTORY_KINDS,
    VERSION,
    DatasetError,
    DatasetMismatchError,
    dataset_trajectory,
    frame_labels,
    iter_labels,
    read_exr,
    render_dataset,
)
from scet_render.dataset.manifest import read_manifest, setup_fingerprint
from scet_render.render import SensorModel
from scet_render.simulate import ground_truth_glints

FRAMES = 3
SPP = 2
SEED = 7


def half_resolution(setup):
    """The setup imaged at half the resolution: same field of view, same strobe timing."""
    cam = setup.camera
    camera = Camera(cam.position_m, cam.rotation, cam.fx_px / 2, cam.fy_px / 2,
                    (cam.cx_px + 0.5) / 2 - 0.5, (cam.cy_px + 0.5) / 2 - 0.5,
                    cam.width_px // 2, cam.height_px // 2)
    if setup.sensor.total_lines % 2:
        raise ValueError("half_resolution needs an even total_lines")
    sensor = replace(setup.sensor, total_lines=setup.sensor.total_lines // 2,
                     visible_lines=cam.height_px // 2)
    return replace(setup, camera=camera, sensor=sensor)


def tree_digest(root: Path) -> dict:
    """{relative path: sha256} of every file under ``root``."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def paper():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def small(paper):
    return half_resolution(paper)


# --------------------------------------------------------------------------- trajectories


@pytest.mark.parametrize("kind", TRAJECTORY_KINDS)
def test_trajectory_covers_every_frame_and_looks_at_the_screen(paper, kind):
    frames = 64
    traj = dataset_trajectory(paper, kind, frames, seed=3)
    assert traj.duration_s >= (frames + 1) * paper.sensor.frame_period_s
    sc = paper.screen
    for t in (traj.to_target_m, traj.from_target_m):
        assert np.all((t[:, 0] >= sc.x_range_m[0]) & (t[:, 0] <= sc.x_range_m[1]))
        assert np.all((t[:, 1] >= sc.y_range_m[0]) & (t[:, 1] <= sc.y_range_m[1]))
        assert np.allclose(t[:, 2], sc.z_m)
    again = dataset_trajectory(paper, kind, frames, seed=3)
    other = dataset_trajectory(paper, kind, frames, seed=4)
    times = np.linspace(0.0, traj.duration_s, 500)
    assert np.array_equal(np.stack(traj.angles_at(times)), np.stack(again.angles_at(times)))
    if kind != "grid":  # the grid's order is fixed; only its fixational noise is seeded
        assert not np.array_equal(traj.to_target_m[:1], other.to_target_m[:1])
    assert not np.array_equal(np.stack(traj.angles_at(times)), np.stack(other.angles_at(times)))


def test_grid_trajectory_walks_the_24x15_cells_in_order(paper):
    traj = dataset_trajectory(paper, "grid", 64, seed=0)
    fixations = traj.to_target_m[traj.kind == 0]
    assert np.allclose(fixations, paper.screen.grid(24, 15)[: len(fixations)])


# --------------------------------------------------------------------------- labels


@pytest.mark.parametrize("frame", [0, 1, 5])
def test_labels_follow_the_banding_model(small, frame):
    """Band rows of each label against the closed-form row weights w_j(y) of Eqs. (2)-(3)."""
    traj = dataset_trajectory(small, "saccades", 8, seed=1)
    labels = frame_labels(small, traj, frame)
    j, s, w = row_pulse_weights(small.sensor, small.strobe, frame)
    lit = [int(jj) for jj, col in zip(j, w.T) if np.any(col > 0)]
    assert [lab["strobe"] for lab in labels] == lit
    for lab in labels:
        col = w[:, list(j).index(lab["strobe"])]
        rows = np.flatnonzero(col > 0)
        assert (lab["first_row"], lab["last_row"]) == (rows[0], rows[-1])
        start, stop = lab["full_rows"]
        full = np.zeros(col.size, dtype=bool)
        full[start:stop] = True
        # Δe = 1 ms >= Δs = 100 µs: the plateau rows collect the whole pulse, no other row does.
        assert np.allclose(col[full], 1.0)
        assert np.all(col[~full] < 1.0 - 1e-9)
        assert lab["pulse_start_s"] == pytest.approx(s[list(j).index(lab["strobe"])], abs=1e-15)
        assert lab["time_s"] == pytest.approx(
            strobe_instant(lab["pulse_start_s"], small.strobe.pulse_s), abs=1e-15)


def test_labels_carry_the_pose_and_glints_at_the_strobe_instant(paper):
    traj = dataset_trajectory(paper, "saccades", 4, seed=2)
    labels = [lab for f in range(4) for lab in frame_labels(paper, traj, f)]
    t = np.array([lab["time_s"] for lab in labels])
    yaw, pitch = traj.angles_at(t)
    glints, visible, center = ground_truth_glints(paper, yaw, pitch)
    for i, lab in enumerate(labels):
        assert (lab["yaw_rad"], lab["pitch_rad"]) == (yaw[i], pitch[i])
        assert lab["target_m"] == traj.target_at(t[i]).tolist()
        assert lab["cornea_center_m"] == center[i].tolist()
        assert lab["glints_visible"] == visible[i].tolist()
        assert len(lab["glints_px"]) == paper.lights.count
        for g, want in zip(lab["glints_px"], glints[i]):
            assert (g is None) == (not np.all(np.isfinite(want)))
            if g is not None:
                assert g == want.tolist()
        assert sum(lab["glints_visible"]) >= 30  # the paper's arc keeps >= 36 of 40 on screen


# --------------------------------------------------------------------------- readers and refusals


def test_read_manifest_checks_format_and_version(tmp_path):
    with pytest.raises(DatasetError, match="no such file"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "other", "version": 1}))
    with pytest.raises(DatasetError, match="format"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"format": FORMAT, "version": VERSION + 1}))
    with pytest.raises(DatasetError, match="version"):
        read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(DatasetError, match="cannot read"):
        read_manifest(tmp_path)


def test_refuses_to_write_into_a_foreign_folder(tmp_path, paper):
    (tmp_path / "notes.txt").write_text("precious")
    with pytest.raises(DatasetError, match="not a SCET dataset"):
        render_dataset(paper, tmp_path, frames=1)
    assert (tmp_path / "notes.txt").read_text() == "precious"


@pytest.mark.parametrize("kwargs, match", [
    ({"frames": 0}, "frames"), ({"frames": 2.0}, "frames"), ({"frames": 1, "seed": -1}, "seed"),
    ({"frames": 1, "trajectory": "zigzag"}, "trajectory"), ({"frames": 1, "spp": 0}, "spp"),
])
def test_bad_arguments_are_refused(tmp_path, paper, kwargs, match):
    with pytest.raises(ValueError, match=match):
        render_dataset(paper, tmp_path / "d", **kwargs)
    assert not (tmp_path / "d").exists()


def test_setup_fingerprint_of_datasets_rendered_before_later_fields(paper):
    """paper_sim's fingerprint as written by the code before the conic cornea and the moving
    lids existed (commit f24169d): datasets rendered then still resume and compare equal."""
    assert setup_fingerprint(paper) == \
        "3098afe1dda6ce85dc3f7e3174bc17bc84ec658f472633092cfcae423793c661"


def test_setup_fingerprint_sees_changes_made_in_code(paper, small):
    assert setup_fingerprint(paper) == setup_fingerprint(load_scene("paper_sim"))
    assert setup_fingerprint(paper) != setup_fingerprint(small)


# --------------------------------------------------------------------------- rendered datasets


@pytest.fixture(scope="module")
def renderer_available():
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is needed to render datasets")
    pytest.importorskip("scet_render.render.rolling_shutter",
                        reason="the Mitsuba renderer (scet_render.render.rolling_shutter) is not there")


@pytest.fixture(scope="module")
def dataset(renderer_available, small, tmp_path_factory):
    """A tiny dataset rendered once, uninterrupted; tests must not modify it."""
    out = tmp_path_factory.mktemp("ds") / "uninterrupted"
    calls = []
    summary = render_dataset(small, out, frames=FRAMES, spp=SPP, trajectory="saccades",
                             seed=SEED, progress=lambda done, total: calls.append((done, total)))
    assert summary.frames_rendered == tuple(range(FRAMES)) and summary.frames_skipped == ()
    assert calls == [(k, FRAMES) for k in range(FRAMES + 1)]
    return out


def test_layout(dataset):
    names = sorted(str(p.relative_to(dataset)) for p in dataset.rglob("*"))
    want = ["frames", "labels.jsonl", "manifest.json"]
    want += [f"frames/{f:06d}{ext}" for f in range(FRAMES)
             for ext in (".exr", ".png", "_mask.png")]
    assert names == sorted(want)


def test_manifest_describes_the_run(dataset, small):
    m = read_manifest(dataset)
    assert (m["format"], m["version"]) == ("scet-dataset", 1)
    text = Path(small.source).read_text(encoding="utf-8")
    # The setup is paper_sim halved in code: the manifest records the effective scene (the
    # text that loads into exactly the setup rendered) and the file's sha256 beside it.
    effective = m["scene"]["toml"]
    assert m["scene"]["name"] == "paper_sim" and m["scene"]["overridden"] == ["camera", "sensor"]
    assert setup_differences(parse_scene(effective), small) == []
    assert m["scene"]["sha256"] == hashlib.sha256(effective.encode()).hexdigest()
    assert m["scene"]["file_sha256"] == hashlib.sha256(text.encode()).hexdigest() == small.source_sha256
    assert m["setup_sha256"] == setup_fingerprint(small)
    assert set(m["software"]) >= {"scet", "numpy", "mitsuba", "drjit"}
    assert m["software"]["numpy"] == np.__version__
    assert (m["seed"], m["trajectory"], m["frames"]) == (SEED, "saccades", FRAMES)
    assert m["render"]["spp"] == SPP and isinstance(m["render"]["variant"], str)
    assert m["image"] == {"width_px": 320, "height_px": 240, "png_bit_depth": 16}
    assert SensorModel.from_dict(m["sensor"]) == SensorModel.from_sensor(small.sensor)


def test_exr_holds_float32_radiance_and_the_strobe_header(dataset, small):
    import OpenEXR

    labels = list(iter_labels(dataset))
    for f in range(FRAMES):
        path = dataset / "frames" / f"{f:06d}.exr"
        with OpenEXR.File(str(path)) as exr:
            header = dict(exr.header())
            assert list(exr.channels()) == ["Y"]
        assert header["compression"] == OpenEXR.ZIP_COMPRESSION  # lossless
        assert header["scet_format"] == FORMAT and header["scet_version"] == VERSION
        exr = read_exr(path)
        assert exr.radiance.dtype == np.float32 and exr.radiance.shape == (240, 320)
        assert np.all(np.isfinite(exr.radiance)) and np.all(exr.radiance >= 0)
        # The sha256 of the effective scene the manifest records (the file's, halved in code).
        assert exr.frame == f and exr.scene_sha256 == read_manifest(dataset)["scene"]["sha256"]
        # The rendered pulses are exactly the labelled strobes, posed at the labelled instants.
        lab = [lb for lb in labels if lb.frame == f]
        assert exr.pulse_indices.tolist() == [lb.strobe for lb in lab]
        assert exr.strobe_times_s.tolist() == [lb.time_s for lb in lab]


def test_exr_radiance_is_the_renderer_output_bit_for_bit(dataset, small):
    """A fresh renderer reproduces a stored frame: frames depend on (seed, frame) only."""
    from scet_render.dataset.writer import _make_renderer

    renderer = _make_renderer(small, spp=SPP, variant=read_manifest(dataset)["render"]["variant"],
                              cornea="dielectric", seed=SEED)
    traj = dataset_trajectory(small, "saccades", FRAMES, SEED)
    frame = renderer.render_frame(traj, FRAMES - 1)
    stored = read_exr(dataset / "frames" / f"{FRAMES - 1:06d}.exr")
    assert np.array_equal(frame.radiance, stored.radiance)


def test_png_is_the_sensor_model_applied_to_the_exr(dataset, small):
    model = SensorModel.from_sensor(small.sensor)
    for f in range(FRAMES):
        png = cv2.imread(str(dataset / "frames" / f"{f:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert png.dtype == np.uint16 and png.shape == (240, 320)
        assert png.max() <= 1023
        radiance = read_exr(dataset / "frames" / f"{f:06d}.exr").radiance
        # Per-frame noise from SeedSequence([seed, sensor stream 2, frame]).
        want = model.apply(radiance, np.random.SeedSequence([SEED, 2, f]))
        assert np.array_equal(png, want)
        # The dark quarter (background outside the lit bands) sits near the black level; the
        # median does not since the iris is lit through the cornea (MNEE): 23 DN.
        assert np.percentile(png, 25) == pytest.approx(16, abs=4)


def test_glints_land_at_the_exposure_times_their_fresnel_gain(renderer_available, small,
                                                               tmp_path):
    """The default exposure puts a glint of normal-incidence reflectance F0 at 70 % of the ADC
    range; the conductor cornea renders the dielectric's F(theta) exactly at 1 spp (a
    dielectric would need hundreds of spp to converge), so a glint in a fully lit row reads
    16 + 0.7 (1023 - 16) F / F0 DN, and those above full scale clip at 1023. F from the
    estimator's own flux model (estimator.calibration.model_flux: the pixel ray meets the
    labelled cornea; its dielectric over constant Fresnel is F)."""
    from estimator.calibration import model_flux

    render_dataset(small, tmp_path, frames=1, spp=1, seed=3, cornea="conductor")
    png = cv2.imread(str(tmp_path / "frames" / "000000.png"), cv2.IMREAD_UNCHANGED)
    n = small.eye.refractive_index
    f0 = ((n - 1.0) / (n + 1.0)) ** 2
    peaks, want = [], []
    for lab in iter_labels(tmp_path):
        start, stop = lab.full_rows
        args = (small.camera, lab.cornea_center_m, small.eye.cornea_radius_m,
                small.lights_world_m, lab.glints_px)
        gain = model_flux(*args, fresnel="dielectric") / model_flux(*args, fresnel="constant") / f0
        for (u, v), seen, k in zip(lab.glints_px, lab.glints_visible, gain):
            if seen and start + 2 <= v < stop - 2 and 2 <= u < png.shape[1] - 2:
                ui, vi = int(round(u)), int(round(v))
                peaks.append(int(png[vi - 2:vi + 3, ui - 2:ui + 3].max()))
                want.append(16 + 0.7 * (1023 - 16) * k)
    peaks, want = np.array(peaks), np.array(want)
    below = want < 950
    # 18 glints below full scale and 6 above it in this frame (seed 3).
    assert below.sum() >= 10 and (want > 1150).sum() >= 3
    assert np.all(want >= 16 + 0.7 * 1007 - 1)  # F >= F0
    assert np.all(peaks[below] < 1023)
    # Half-resolution pixels are not always fully covered: 6 % either way on the median (an
    # F0-scaled mirror reads 0.7-0.9 of these).
    assert np.median(peaks[below] / want[below]) == pytest.approx(1.0, abs=0.06)
    assert np.all(peaks[want > 1150] == 1023)


def test_labels_file_is_every_visible_strobe_of_every_frame(dataset, small):
    traj = dataset_trajectory(small, "saccades", FRAMES, SEED)
    want = [lab for f in range(FRAMES) for lab in frame_labels(small, traj, f)]
    lines = (dataset / LABELS_NAME).read_text().splitlines()
    assert [json.loads(line) for line in lines] == want
    got = list(iter_labels(dataset))
    assert len(got) == len(want) > 0
    assert [(g.frame, g.strobe) for g in got] == [(w["frame"], w["strobe"]) for w in want]
    g = got[len(got) // 2]
    assert g.glints_px.shape == (small.lights.count, 2) and g.glints_visible.dtype == bool


def test_8_bit_sensor_writes_8_bit_png(renderer_available, small, tmp_path):
    sensor = SensorModel.from_sensor(small.sensor, bit_depth=8)
    render_dataset(small, tmp_path, frames=1, spp=1, seed=1, sensor=sensor)
    png = cv2.imread(str(tmp_path / "frames" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint8
    assert read_manifest(tmp_path)["image"]["png_bit_depth"] == 8


class Crash(RuntimeError):
    pass


def test_resume_after_a_crash_gives_the_uninterrupted_dataset(dataset, small, tmp_path):
    out = tmp_path / "resumed"
    kwargs = dict(frames=FRAMES, spp=SPP, trajectory="saccades", seed=SEED)

    def crash_after_first_frame(done, total):
        if done == 1:
            raise Crash

    with pytest.raises(Crash):
        render_dataset(small, out, progress=crash_after_first_frame, **kwargs)
    assert not (out / LABELS_NAME).exists()
    with pytest.raises(DatasetError, match="did not finish"):
        next(iter_labels(out))
    # A kill during a write leaves a partial file behind; the rerun discards it.
    (out / "frames" / "000001.exr.partial").write_bytes(b"\x76\x2f\x31\x01 truncated")
    summary = render_dataset(small, out, **kwargs)
    assert summary.frames_skipped == (0,) and summary.frames_rendered == (1, 2)
    assert tree_digest(out) == tree_digest(dataset)


@pytest.mark.slow
def test_resume_after_sigkill_gives_the_uninterrupted_dataset(dataset, small, tmp_path):
    """A real kill: a child process is SIGKILLed once its first frame is on disk."""
    out = tmp_path / "killed"
    script = (
        "from estimator.scene import load_scene\n"
        "from scet_render.dataset import render_dataset\n"
        "from tests.scet_render.test_dataset import half_resolution\n"
        "render_dataset(half_resolution(load_scene('paper_sim')), {out!r}, frames={frames}, "
        "spp={spp}, trajectory='saccades', seed={seed})\n"
    ).format(out=str(out), frames=FRAMES, spp=SPP, seed=SEED)
    root = Path(__file__).resolve().parents[2]
    child = subprocess.Popen([sys.executable, "-c", script], cwd=root,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120.0
        while not (out / "frames" / "000000.png").exists():
            if child.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"child exited or stalled before its first frame: "
                            f"{child.stderr.read().decode()[-2000:]}")
            time.sleep(0.01)
        child.send_signal(signal.SIGKILL)
    finally:
        child.wait()
        child.stderr.close()
    assert not (out / LABELS_NAME).exists(), "the child finished before it could be killed"
    render_dataset(small, out, frames=FRAMES, spp=SPP, trajectory="saccades", seed=SEED)
    assert tree_digest(out) == tree_digest(dataset)


def test_rerunning_a_finished_dataset_changes_nothing(dataset, small):
    before = tree_digest(dataset)
    summary = render_dataset(small, dataset, frames=FRAMES, spp=SPP, trajectory="saccades",
                             seed=SEED)
    assert summary.frames_rendered == () and summary.frames_skipped == tuple(range(FRAMES))
    assert tree_digest(dataset) == before


@pytest.mark.parametrize("change, names", [
    ({"seed": SEED + 1}, ["seed"]),
    ({"frames": FRAMES + 1}, ["frames"]),
    ({"trajectory": "grid"}, ["trajectory"]),
    ({"spp": SPP + 1}, ["render.spp"]),
])
def test_refuses_a_dataset_made_with_other_arguments(dataset, small, change, names):
    before = tree_digest(dataset)
    kwargs = dict(frames=FRAMES, spp=SPP, trajectory="saccades", seed=SEED)
    kwargs.update(change)
    with pytest.raises(DatasetMismatchError) as err:
        render_dataset(small, dataset, **kwargs)
    for name in names:
        assert f"{name}: dataset has" in str(err.value)
    assert tree_digest(dataset) == before


def test_refuses_a_dataset_of_another_scene(dataset, small):
    before = tree_digest(dataset)
    other = half_resolution(load_scene("paper_sim_doubled"))
    with pytest.raises(DatasetMismatchError) as err:
        render_dataset(other, dataset, frames=FRAMES, spp=SPP, trajectory="saccades", seed=SEED)
    message = str(err.value)
    assert "scene.name" in message and "scene.sha256" in message and "setup_sha256" in message
    # Same scene file, other camera: the fingerprint, and the effective scene the dataset
    # records (its camera overridden in code), tell them apart.
    with pytest.raises(DatasetMismatchError, match="setup_sha256") as err:
        render_dataset(load_scene("paper_sim"), dataset, frames=FRAMES, spp=SPP,
                       trajectory="saccades", seed=SEED)
    assert "scene.overridden: dataset has" in str(err.value)
    assert tree_digest(dataset) == before
