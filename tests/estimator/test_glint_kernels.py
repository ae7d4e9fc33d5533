"""The compiled steps of glint detection (:mod:`estimator.glints.kernels`) against OpenCV's
connected components and the numpy pixel-by-pixel reference, on what the detector's own tests
do not reach: arbitrary masks, levels far beyond 10 bits, and the window's views.

The detections of every fast path are held to the reference on eye frames, borders, blooms,
blends and 8/16-bit and float frames in ``test_glints.py``.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from estimator.glints import kernels as glint_kernels
from estimator.glints.noise import _NoiseModel
from estimator.glints import DetectionParams, GlintDetector, detect_glints
from estimator.scene import load_scene
from tests.estimator.simulated import ground_truth_glints
from tests.estimator.test_glints import (  # noqa: F401 (pixel_path: a fixture)
    assert_same_detections,
    banded_frame,
    needs_compiled_kernels,
    pixel_path,
)

pytestmark = needs_compiled_kernels


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


def test_enabled_with_numba():
    assert glint_kernels.ENABLED


@pytest.mark.parametrize("density", [0.002, 0.05, 0.3])
def test_components_are_opencvs_eight_connected_components(density):
    """On random masks (isolated pixels to a percolating tangle, touching every border): the
    same partition into 8-connected components as OpenCV, labelled in the order of their
    first pixels row by row, with their areas and inclusive boxes."""
    rng = np.random.default_rng(int(density * 1000))
    height, width = 61, 97
    mask = rng.random((height, width)) < density
    top = np.where(mask, 100, 0).astype(np.uint16)  # above any threshold where masked
    img = top + np.uint16(20)
    model = _NoiseModel.measure(np.zeros(64, np.int64), np.full(64, 20, np.int64),
                                DetectionParams())
    labels, area, y0, y1, x0, x1 = glint_kernels.components(np.flatnonzero(mask), top, img,
                                                            model, DetectionParams())
    n, ref = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    assert area.size == n - 1
    # The same partition: a one-to-one map between the two labellings on the masked pixels.
    pairs = np.unique(np.stack([labels[mask], ref[mask]]), axis=1)
    assert pairs.shape[1] == n - 1
    assert np.array_equal(labels[~mask], np.zeros((~mask).sum(), np.int32))
    # Labels in the order of the components' first pixels, row by row.
    first = np.array([np.flatnonzero((labels == c).ravel())[0] for c in range(1, n)])
    assert (np.diff(first) > 0).all()
    for c in range(1, n):
        ys, xs = np.nonzero(labels == c)
        assert area[c - 1] == ys.size
        assert (y0[c - 1], y1[c - 1], x0[c - 1], x1[c - 1]) == (ys.min(), ys.max(), xs.min(),
                                                                xs.max())


def test_levels_beyond_the_first_tables(setup, pixel_path):
    """A 16-bit frame whose background sits at ~4,000-5,000 DN (a 12-bit sensor, scaled): the
    noise tables are built for 256 levels first and grown when a pixel needs more; the same
    detections as the reference."""
    rng = np.random.default_rng(5)
    g, vis, _ = ground_truth_glints(setup, 0.05, -0.02)
    frame = banded_frame(setup, g[vis], 1.0, 400.0, rng).astype(np.uint16) * np.uint16(4)
    frame += np.uint16(3000)
    params = DetectionParams(saturation_dn=65535.0)
    det = detect_glints(frame, setup, params=params)
    assert len(det) >= 20
    assert_same_detections(det, pixel_path(frame, setup, params=params))


def test_window_views_match_the_whole_frame(setup):
    """The detector hands the kernels views of the window (not copies): a window's glints are
    those the whole frame gives, on frames of a slow drift."""
    rng = np.random.default_rng(8)
    window, whole = GlintDetector(setup), GlintDetector(setup, track_roi=False)
    for f in range(6):
        g, vis, _ = ground_truth_glints(setup, 0.1 + 0.003 * f, -0.04)
        frame = banded_frame(setup, g[vis], 0.9, 350.0, rng, frame_index=f)
        a, b = window(frame, f), whole(frame, f)
        assert_same_detections(a, b)
    assert window.windowed >= 4


def test_label_image_holds_no_labels_of_the_previous_call():
    """The label image is reused per thread and only the last call's pixels are cleared:
    after a dense mask, then windows of other sizes, nothing but the new labels remains."""
    rng = np.random.default_rng(3)
    model = _NoiseModel.measure(np.zeros(64, np.int64), np.full(64, 20, np.int64),
                                DetectionParams())
    for height, width, density in ((80, 120, 0.4), (50, 60, 0.01), (90, 130, 0.2), (40, 41, 0)):
        mask = rng.random((height, width)) < density
        top = np.where(mask, 100, 0).astype(np.uint16)
        labels, area = glint_kernels.components(np.flatnonzero(mask), top, top + np.uint16(20),
                                                model, DetectionParams())[:2]
        assert labels.shape == (height, width)
        assert ((labels != 0) == mask).all()


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_blend_maxima_is_the_numpy_split(dtype):
    """The compiled split of an elongated spot (its separated maxima) is the numpy one, pixel
    index for pixel index, on 400 spots of two or three noisy Gaussian peaks at random
    separations and heights (some split, some do not: a saddle above 0.6 of the lower peak,
    maxima at the image border, flat tops)."""
    from estimator.glints.spots import _blend_maxima

    rng = np.random.default_rng(11)
    params = DetectionParams()
    split = kept = 0
    for _ in range(400):
        h, w = 24, 24
        yy, xx = np.mgrid[:h, :w]
        top = np.zeros((h, w))
        for _ in range(int(rng.integers(1, 4))):
            cy, cx = rng.uniform(0, h - 1), rng.uniform(0, w - 1)
            top += rng.uniform(20, 400) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2)
                                                 / (2 * rng.uniform(0.6, 2.0) ** 2))
        top += rng.normal(0, 3, top.shape)
        top = np.clip(top, 0, None)
        top = np.rint(top).astype(dtype) if dtype == np.uint16 else top.astype(dtype)
        y0, x0 = rng.integers(0, 8, 2)
        ys, xs = (a.ravel().astype(np.int64) for a in np.mgrid[y0:y0 + 16, x0:x0 + 16])
        floor = rng.uniform(0, 10)
        val = top[ys, xs].astype(np.float64) - floor
        own = val > rng.uniform(5, 40)
        ref = _blend_maxima(ys, xs, own, val, top, params)
        got = glint_kernels.blend_maxima(ys, xs, own, val, top, params)
        assert np.array_equal(ref, got)
        split += ref.size > 0
        kept += ref.size == 0
    assert split > 40 and kept > 40  # both outcomes exercised


def test_deblend_is_the_numpy_split_of_every_spot():
    """The compiled split of a frame's elongated spots in one call is the numpy loop over
    them: the same spots split, and the new spots' pixels, rows, flags and edges equal array
    for array, on 300 spots of one to three noisy Gaussian peaks side by side in one top-hat
    (some split into two or three, some not)."""
    from estimator.glints.spots import _blend_maxima, _deblend, _Pixels

    rng = np.random.default_rng(12)
    params = DetectionParams()
    n, h, w = 300, 24, 24
    top = np.zeros((h, w * n))
    yy, xx = np.mgrid[:h, :w]
    segs = []
    for s in range(n):
        for _ in range(int(rng.integers(1, 4))):
            cy, cx = rng.uniform(0, h - 1), rng.uniform(0, w - 1)
            top[:, s * w:(s + 1) * w] += rng.uniform(20, 400) * np.exp(
                -((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * rng.uniform(0.6, 2.0) ** 2))
        y0, x0 = rng.integers(0, 8, 2)
        ys, xs = (a.ravel().astype(np.int64) for a in np.mgrid[y0:y0 + 16, x0:x0 + 16])
        segs.append((ys, xs + s * w))
    top = np.rint(np.clip(top + rng.normal(0, 3, top.shape), 0, None)).astype(np.uint16)
    ys = np.concatenate([a for a, _ in segs])
    xs = np.concatenate([b for _, b in segs])
    val = top[ys, xs].astype(np.float64) - rng.uniform(0, 10)
    own = val > 30.0
    starts = np.arange(n, dtype=np.int64) * 256
    px = _Pixels(n, np.repeat(np.arange(n), 256), starts, ys, xs, own,
                 own | (rng.uniform(size=ys.size) < 0.5), np.zeros(n, np.int64),
                 np.zeros(n, np.int64), rng.uniform(size=n) < 0.3)
    ref, ref_split = _deblend(px, val, np.arange(n), top, params, _blend_maxima)
    got, got_split = glint_kernels.deblend(px, val, top, params)
    assert np.array_equal(ref_split, got_split)
    assert 30 < len(ref_split) < n - 30  # both outcomes exercised
    assert ref.n == got.n and ref.n > len(ref_split)
    for name in ("seg", "starts", "ys", "xs", "own", "usable", "row0", "row1", "edge"):
        a, b = getattr(ref, name), getattr(got, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
