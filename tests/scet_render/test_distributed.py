"""Datasets beyond one process: Ray workers give the serial run's bytes (a killed worker too),
damaged frames are rendered again, and the reader and the verifier see what is on disk.

The reference is test_dataset's ``dataset`` fixture: the same tiny dataset (320x240, 3 frames,
2 spp, saccades, seed 7) rendered serially, uninterrupted.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from scet_render.dataset import (
    LABELS_NAME,
    iter_labels,
    open_dataset,
    read_exr,
    render_dataset,
    verify_dataset,
)
from scet_render.dataset.distributed import NAMESPACE, render_dataset_ray
from tests.scet_render.test_dataset import (  # noqa: F401 (fixtures)
    FRAMES,
    SEED,
    SPP,
    dataset,
    paper,
    renderer_available,
    small,
    tree_digest,
)

ray = pytest.importorskip("ray")
KWARGS = dict(frames=FRAMES, spp=SPP, trajectory="saccades", seed=SEED)


def test_two_workers_give_the_serial_bytes(dataset, small, tmp_path):
    out = tmp_path / "ray2"
    calls = []
    summary = render_dataset_ray(small, out, workers=2, progress=lambda d, t: calls.append(d),
                                 **KWARGS)
    assert summary.frames_rendered == tuple(range(FRAMES))
    assert calls == list(range(FRAMES + 1))
    assert tree_digest(out) == tree_digest(dataset)   # manifest and labels included


def test_workers_render_without_eyelids_as_the_serial_run(small, tmp_path):
    """eyelid_openness reaches the actors (the plan carries it): a lidless frame, serial and
    on a worker, byte for byte; and it differs from the lidded one (the option does act)."""
    kw = dict(frames=1, spp=SPP, trajectory="saccades", seed=SEED)
    render_dataset(small, tmp_path / "serial", eyelid_openness=None, **kw)
    render_dataset_ray(small, tmp_path / "ray", workers=1, eyelid_openness=None, **kw)
    assert tree_digest(tmp_path / "ray") == tree_digest(tmp_path / "serial")
    render_dataset(small, tmp_path / "lids", **kw)
    assert tree_digest(tmp_path / "lids") != tree_digest(tmp_path / "serial")


def test_a_killed_worker_is_restarted_and_the_dataset_is_the_same(dataset, small, tmp_path):
    out = tmp_path / "killed_worker"
    killed = []

    def kill_a_worker(done, total):
        if done == 1 and not killed:
            actor = ray.get_actor("scet-render-0", namespace=NAMESPACE)
            ray.kill(actor, no_restart=False)   # as a crash: Ray restarts it and retries its task
            killed.append(done)

    render_dataset_ray(small, out, workers=2, progress=kill_a_worker, **KWARGS)
    assert killed == [1]
    assert tree_digest(out) == tree_digest(dataset)


def test_a_dead_writers_temporary_is_swept_at_the_end(dataset, small, tmp_path):
    """A worker killed mid-write leaves its unique temporary behind (its task is retried by
    another writer under another name); the finished folder holds the dataset alone."""
    out = tmp_path / "litter"
    shutil.copytree(dataset, out)
    (out / "frames" / "000002.png").unlink()

    def die_mid_write(done, total):
        if done == 2:  # the finished frames counted; before the missing one is rendered
            (out / "frames" / "000002.png.ab12345-6-7.partial").write_bytes(b"half a frame")

    render_dataset(small, out, progress=die_mid_write, **KWARGS)
    assert tree_digest(out) == tree_digest(dataset)


def test_a_finished_dataset_needs_no_worker(dataset, tmp_path, small):
    out = tmp_path / "copy"
    shutil.copytree(dataset, out)
    summary = render_dataset_ray(small, out, workers=2, **KWARGS)
    assert summary.frames_rendered == () and not ray.is_initialized()
    assert tree_digest(out) == tree_digest(dataset)


@pytest.mark.parametrize("name", ["000001.png", "000002.exr"])
def test_a_truncated_frame_is_rendered_again(dataset, small, tmp_path, name):
    out = tmp_path / "damaged"
    shutil.copytree(dataset, out)
    path = out / "frames" / name
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # a crash mid-copy
    problems = verify_dataset(out)
    assert len(problems) == 1 and "1 of 3 frames missing or damaged" in problems[0]
    summary = render_dataset(small, out, **KWARGS)
    assert summary.frames_rendered == (int(name[:6]),)
    assert tree_digest(out) == tree_digest(dataset) and verify_dataset(out) == []


def test_verify_names_what_is_wrong(dataset, tmp_path):
    assert verify_dataset(dataset) == []
    out = tmp_path / "odd"
    shutil.copytree(dataset, out)
    (out / "frames" / "000009.png").write_bytes(b"stray")
    lines = (out / LABELS_NAME).read_text().splitlines()
    (out / LABELS_NAME).write_text("\n".join(lines[:2] + lines[:1]) + "\n")  # a repeated line
    problems = verify_dataset(out)
    assert any("files the manifest does not name" in p and "000009.png" in p for p in problems)
    assert any("out of order or repeated" in p for p in problems)
    assert "no such file" in verify_dataset(tmp_path)[0]


def test_the_reader_gives_frames_with_their_labels(dataset):
    ds = open_dataset(dataset)
    labels = list(iter_labels(dataset))
    assert len(ds) == FRAMES and ds.n_labels == len(labels)
    for frame in ds:
        mine = [lb for lb in labels if lb.frame == frame.index]
        assert [lb.strobe for lb in frame.labels] == [lb.strobe for lb in mine]
    counts = ds[1].counts()
    assert counts.dtype == np.uint16 and counts.shape == (240, 320)
    assert np.array_equal(ds[-1].radiance(), read_exr(dataset / "frames" / "000002.exr").radiance)
    assert [f.index for f in ds[0:2]] == [0, 1]
    with pytest.raises(IndexError):
        ds[FRAMES]


@pytest.mark.slow
def test_a_killed_driver_is_resumed_with_the_same_bytes(dataset, tmp_path):
    """The driver SIGKILLed once its first frame is on disk, then the same command again."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "killed_driver"
    script = (
        "from estimator.scene import load_scene\n"
        "from scet_render.dataset.distributed import render_dataset_ray\n"
        "from tests.scet_render.test_dataset import half_resolution\n"
        f"render_dataset_ray(half_resolution(load_scene('paper_sim')), {str(out)!r}, workers=2, "
        f"frames={FRAMES}, spp={SPP}, trajectory='saccades', seed={SEED})\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path.parents[0]) + os.pathsep
           + os.environ.get("PYTHONPATH", "")}
    root = __import__("pathlib").Path(__file__).resolve().parents[2]
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=root, env=env,
                            start_new_session=True)
    deadline = time.monotonic() + 300
    while not (out / "frames" / "000000.png").exists() and proc.poll() is None:
        if time.monotonic() > deadline:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and the Ray it started
    proc.wait()
    assert not (out / LABELS_NAME).exists()
    subprocess.run([sys.executable, "-c", script], cwd=root, env=env, check=True, timeout=600)
    assert tree_digest(out) == tree_digest(dataset)


_RESUME = """
import json, sys
from estimator.scene import load_scene
from scet_render.dataset import DatasetMismatchError, render_dataset
from tests.scet_render.test_dataset import half_resolution
try:
    render_dataset(half_resolution(load_scene('paper_sim')), sys.argv[1], frames={frames},
                   spp={spp}, trajectory='saccades', seed={seed})
except DatasetMismatchError as exc:
    print(exc)
    sys.exit(3)
"""


@pytest.mark.parametrize("width", ["half", 64])
def test_a_resume_is_pinned_to_the_recorded_vector_width_or_refused(dataset, tmp_path, width):
    """A folder whose frames were rendered half as many lanes wide as this CPU's (8 on an
    AVX-512 CPU, 4 on an AVX2 one) is resumed that wide (its missing frame's radiance then
    differs from this CPU's own render); one recorded at 64 lanes, more than any CPU here
    runs, is refused. In a child process: a pinned width stays for the process's later
    kernels."""
    import json
    import subprocess
    import sys

    from estimator.formats import MANIFEST_NAME

    out = tmp_path / f"w{width}"
    shutil.copytree(dataset, out)
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    if "llvm" not in manifest["render"]["renderer"]:
        pytest.skip("not rendered on the LLVM backend")
    if width == "half":
        width = manifest["render"]["renderer"]["llvm"]["vector_width"] // 2
    manifest["render"]["renderer"]["llvm"]["vector_width"] = width
    (out / MANIFEST_NAME).write_text(json.dumps(manifest, indent=1))
    (out / "frames" / "000002.png").unlink()
    root = __import__("pathlib").Path(__file__).resolve().parents[2]
    run = subprocess.run([sys.executable, "-c", _RESUME.format(frames=FRAMES, spp=SPP, seed=SEED),
                          str(out)], cwd=root, capture_output=True, text=True, timeout=600)
    if width == 64:
        assert run.returncode == 3 and "64 lanes wide" in run.stdout, run.stdout + run.stderr
        assert not (out / "frames" / "000002.png").exists()
    else:
        assert run.returncode == 0, run.stderr
        # The radiance differs in its last bits (17 % of the pixels at 320x240 at 8 lanes
        # against 16, up to 0.02 of ~1); the 10-bit counts of this tiny frame happen not to.
        # MNEE's discrete choices (a Newton solve converged or not, a ray just inside the
        # cap or not) may flip in a few iris pixels: each sample carries a whole light there
        # (measured: 0.04 % of the pixels beyond 0.05, at most 0.11).
        new, old = (read_exr(p / "frames" / "000002.exr").radiance for p in (out, dataset))
        far = np.abs(new - old) > 0.05
        assert not np.array_equal(new, old) and far.mean() < 0.005
        assert (out / "frames" / "000001.png").read_bytes() == (
            dataset / "frames" / "000001.png").read_bytes()


def test_calibration_frames_on_two_workers_are_the_serial_bytes(small, tmp_path):
    """``render_calibration`` with workers (``scet validate --workers``, ``scet render
    --calibration --workers``): the same PNGs, labels, timing and scene as the serial run, and a
    folder with every frame present needs no worker."""
    from scet_render.dataset import render_calibration

    kw = dict(spp=SPP, cornea="conductor", seed=SEED, grid=(2, 2))
    render_calibration(small, tmp_path / "serial", **kw)
    calls = []
    render_calibration(small, tmp_path / "ray", workers=2, progress=lambda d, t: calls.append((d, t)),
                       **kw)
    assert tree_digest(tmp_path / "ray") == tree_digest(tmp_path / "serial")
    assert sorted(calls) == [(k, 4) for k in range(1, 5)]
    # ... and a finished folder starts no Ray (a wrong address would fail if it did).
    render_calibration(small, tmp_path / "ray", address="127.0.0.1:1", **kw)
    assert tree_digest(tmp_path / "ray") == tree_digest(tmp_path / "serial")


def test_reproduction_trials_on_two_workers_give_the_serial_numbers():
    """``scet reproduce --workers``: every trial draws from its own generator, so the results of
    Ray tasks are the serial run's exactly, in the same order."""
    from scet_render.cluster import TaskPool, ray_session
    from scet_render.reproduce import ReproductionConfig, run_experiments
    from tests.scet_render.test_reproduce import _same

    cfg = ReproductionConfig(True, 3, (0.0, 0.5), 2, 1, 2, 4, 2, (1.0,), 2, (4, 20))
    serial = run_experiments(cfg)
    labels = []
    with ray_session(workers=2) as r:
        distributed = run_experiments(cfg, lambda d, t, label: labels.append(d), TaskPool(r))
    assert _same(serial, distributed)
    assert sorted(labels) == list(range(1, 2 * 2 + 1 + 2 + 2 + 1))


@pytest.mark.parametrize("workers", [0, -1, True, 1.5])
def test_a_bad_worker_count_is_refused_in_one_line(workers):
    from scet_render.cluster import ray_session

    with pytest.raises(ValueError, match="workers must be an integer >= 1"):
        with ray_session(workers=workers):
            pass
