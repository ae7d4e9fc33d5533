"""Glint detection over a stream of frames: :class:`GlintDetector` keeps the noise
model between frames and searches only a window around the last glints (see the class).
"""

from __future__ import annotations

import math

import numpy as np

from ..eye import EYE_SPEED_MAX_DEG_S, gaze_direction
from ..geometry import project_glints
from ..setup import Setup
from .detector import _detect, _full_scale_and_black, _prepare
from .noise import _NOISE_STEP, _NoiseModel
from .params import DetectionParams, GlintDetections

#: Rows a band's strip (:meth:`GlintDetector.rows_of`) reaches beyond the band's own: a glint
#: lit by the band has its centroid in the band's rows and its pixels within 8 px of it (a
#: saturated glint's bloom, radius ~5.6 px; :class:`DetectionParams` ``max_area_px``).
STRIP_PAD_PX = 8


class GlintDetector:
    """:func:`detect_glints` over the frames of one sequence: the noise model of step 2 is
    measured only now and then, and the search follows the glints in a window.

    **Noise model.** The model is the top-hat's floor and σ as functions of the background
    level L, a property of the sensor (read noise, conversion gain, quantisation) and of the
    top-hat operator, not of where the eye looks: a frame's model serves the frames after it.
    It is measured again

    - when the frame's mean level (on the model's 1-in-64 subsample, glints included) has moved
      by more than ``level_drift`` of the mean above black since the model was measured, or by
      1 DN on a frame near black: exposure, analog gain or illumination changes rescale every
      level and σ(L) with them; 5 % rescales σ by at most 5 %, which moves the 8 σ threshold
      by 0.4 σ (measured false glints per frame: 0.005 at 7.5 σ,
      :attr:`DetectionParams.threshold_sigma`). A blink, the eye leaving the frame or a
      strobe that fails moves the mean by far more. The mean of 4,800 pixels wanders by
      ~σ / 70 from frame to frame: far below either bound.
    - every ``refresh_frames`` frames (default 30, 0.5 s at 60 fps) in any case: slow changes
      the mean does not see (sensor warm-up raising the dark noise, the level histogram
      reshaping as the eye turns, which moves the model's bins) last at most that long;
    - when the frame's dtype changes (8-bit and 10-bit output have different models), and
      after :meth:`reset`.

    **Window** (``track_roi``, on by default). The glints of one eye cover a small part of
    the frame (paper_sim: ~250 x 220 of 640 x 480 px over the whole screen), and steps 1-3 cost
    in proportion to the pixels searched. A frame that measures a noise model is searched
    whole; the frames after it only inside the bounding box of every glint found since that
    frame, grown by ``roi_margin_px`` on each side. The window's glints are exactly those the
    whole frame gives for them (see :func:`_detect`); the whole frame is searched again at
    once when a component touches the window's inner edge (a glint moving out of it, or
    anything larger cut by it) or when the window holds no glint (a blink, a lost eye). A
    glint that appears wholly outside the window (a light that was hidden, a jump larger than
    the margin) is found at the next whole-frame search, at most ``refresh_frames`` frames
    later. The default margin is how far any glint moves in one frame period at
    ``eye_speed_deg_s``: the largest displacement per degree of eye rotation, in any direction,
    of the setup's glints at primary gaze (the closed-form projection, :func:`window_margin_px`).

    **Focus** (``focus``, off by default). Clutter (Monte Carlo fireflies of a render, specular
    highlights, a lamp) spreads detections over the whole frame, and with them the window. With
    ``focus`` the window is instead the box of the points the caller names after each frame
    (:meth:`focus_on`; the tracker names the detections its accepted samples used and the
    glints predicted at its last eye rotation), grown by ``roi_margin_px``: clutter far from
    the eye is not searched. The rules
    above still hold but one: a whole-frame search every ``refresh_frames`` frames, at once
    when the window holds nothing, and after a frame with no identified glint
    (:meth:`focus_on` with none); a component that touches the window's inner edge is dropped
    (clutter crossing it would void nearly every window; a glint there has moved further than
    the margin since the last frame). A glint outside the window is found at the next
    whole-frame search; the window only ever drops detections, and those it keeps are exactly
    the whole frame's.

    The detections carry the model's ``noise_dn`` and ``threshold_dn``: those of the frame it
    was measured on. :attr:`window` is the window the last frame was searched in (None: the
    whole frame); :attr:`frames`, :attr:`windowed` and :attr:`retried` count the frames, those
    searched in a window alone, and windows voided and searched again whole.

    Parameters
    ----------
    setup : Setup
    params : DetectionParams
    refresh_frames : int
        Frames per model and per whole-frame search, >= 1 (1: every frame is measured and
        searched whole, as :func:`detect_glints`).
    level_drift : float
        Relative change of the mean level above black that forces a new model, > 0.
    track_roi : bool
        Search a window around the glints between whole-frame searches.
    roi_margin_px : int, optional
        Growth of the window beyond the glints found (px, >= 0). Default:
        :func:`window_margin_px` of the setup at ``eye_speed_deg_s``.
    eye_speed_deg_s : float
        Eye rotation speed the default margin allows for
        (:data:`estimator.eye.EYE_SPEED_MAX_DEG_S`, 600°/s).
    focus : bool
        Window on the glints named by :meth:`focus_on` rather than on every detection.
    """

    def __init__(self, setup: Setup, params: DetectionParams = DetectionParams(), *,
                 refresh_frames: int = 30, level_drift: float = 0.05, track_roi: bool = True,
                 roi_margin_px: int | None = None,
                 eye_speed_deg_s: float = EYE_SPEED_MAX_DEG_S, focus: bool = False):
        if isinstance(refresh_frames, bool) or not isinstance(refresh_frames, (int, np.integer)) \
                or refresh_frames < 1:
            raise ValueError(f"refresh_frames must be an integer >= 1, got {refresh_frames!r}")
        if not level_drift > 0:
            raise ValueError(f"level_drift must be positive, got {level_drift!r}")
        #: The most a glint moves per degree of eye rotation (:func:`glint_px_per_deg`).
        self.px_per_deg = glint_px_per_deg(setup)
        if roi_margin_px is None:
            roi_margin_px = window_margin_px(setup, eye_speed_deg_s)
        if isinstance(roi_margin_px, bool) or not isinstance(roi_margin_px, (int, np.integer)) \
                or roi_margin_px < 0:
            raise ValueError(f"roi_margin_px must be an integer >= 0, got {roi_margin_px!r}")
        self.setup, self.params = setup, params
        self.refresh_frames, self.level_drift = int(refresh_frames), float(level_drift)
        self.track_roi, self.roi_margin_px = bool(track_roi), int(roi_margin_px)
        self.focus = bool(focus)
        self.measured_at: int | None = None  # frame index of the model in use
        self.measurements = 0  # models measured so far
        self.window: tuple[int, int, int, int] | None = None  # (y0, y1, x0, x1) of the last frame
        self.frames = self.windowed = self.retried = 0
        self._noise: _NoiseModel | None = None
        self._mean = 0.0
        self._dtype = None
        self._age = 0
        self._box: tuple | None = None  # (v min, v max, u min, u max) of the glints found
        self._last: tuple | None = None  # (checked frame, index) of the last windowed frame
        self.strips = 0  # band strips searched again (rows_of)

    def reset(self) -> None:
        """Forget the noise model and the glints: the next frame measures its own model and
        is searched whole."""
        self._noise, self.measured_at, self._box = None, None, None

    def __call__(self, frame, frame_index: int) -> GlintDetections:
        """The glints of the next frame of the sequence (as :func:`detect_glints`)."""
        img, frame_index = _prepare(frame, self.setup, frame_index)
        sample = img[::_NOISE_STEP, ::_NOISE_STEP]
        mean = float(sample.sum(dtype=np.float64)) / sample.size  # 3x faster than .mean()
        noise = self._noise
        if noise is not None:
            black = _full_scale_and_black(img, self.setup.sensor, self.params)[1]
            if (self._age >= self.refresh_frames or img.dtype != self._dtype
                    or abs(mean - self._mean) > max(self.level_drift * (self._mean - black), 1.0)):
                noise = None
        window = self._window(img.shape) if noise is not None else None
        det = None
        if window is not None:
            det, _ = _detect(img, self.setup, frame_index, self.params, noise, window,
                             drop_cut=self.focus)
            if det is None or len(det) == 0:
                det, window = None, None
                self.retried += 1
        if det is None:
            det, model = _detect(img, self.setup, frame_index, self.params, noise)
            if noise is None:
                self._noise, self._mean, self._dtype, self._age = model, mean, img.dtype, 0
                self.measured_at = frame_index
                self.measurements += 1
        self._age += 1
        self.frames += 1
        self.windowed += window is not None
        self.window = window
        self._last = (img, frame_index) if window is not None else None
        self._grow(det, whole=window is None)
        return det

    def rows_of(self, first: int, last: int) -> GlintDetections:
        """The last frame's detections in rows ``first`` .. ``last`` (a band's) and
        :data:`STRIP_PAD_PX` rows either side, searched again across the frame's whole width
        with the noise model its window was searched with: every detection is exactly what
        the whole frame gives for it (:func:`_detect`); a component that touches the strip's
        top or bottom edge inside the frame is dropped, as the focused window drops those
        touching its edge (a glint lit by the band lies wholly within the strip). Only after a
        frame searched in a window (:attr:`window` not None): the tracker's fallback for a
        band where its last sample expects glints beyond the window's edge."""
        if self._last is None:
            raise ValueError("rows_of: the last frame was searched whole already")
        img, frame_index = self._last
        self.strips += 1
        y0, y1 = max(int(first) - STRIP_PAD_PX, 0), min(int(last) + 1 + STRIP_PAD_PX, img.shape[0])
        return _detect(img, self.setup, frame_index, self.params, self._noise,
                       (y0, y1, 0, img.shape[1]), drop_cut=True)[0]

    def _window(self, shape) -> tuple[int, int, int, int] | None:
        if not self.track_roi or self._box is None:
            return None
        m = self.roi_margin_px
        v0, v1, u0, u1 = self._box
        y0, x0 = max(int(v0) - m, 0), max(int(u0) - m, 0)  # the centroids' pixels (v, u >= -0.5)
        y1, x1 = min(int(v1) + m + 2, shape[0]), min(int(u1) + m + 2, shape[1])
        if (y1 - y0) * (x1 - x0) > 0.8 * shape[0] * shape[1]:
            return None  # hardly smaller than the frame: the copies would cost more
        return y0, y1, x0, x1

    def focus_on(self, glints_px) -> None:
        """With ``focus``: the next frame's window is the box of ``glints_px`` (k, 2) (u, v px,
        the last frame's identified glints) grown by the margin; none (k = 0 or None): the
        next frame is searched whole. Without ``focus`` nothing changes."""
        if not self.focus:
            return
        g = None if glints_px is None else np.asarray(glints_px, dtype=np.float64)
        if g is None or g.shape[0] == 0 or self._noise is None:
            self._box = None
            return
        self._box = (float(g[:, 1].min()), float(g[:, 1].max()), float(g[:, 0].min()),
                     float(g[:, 0].max()))

    def _grow(self, det: GlintDetections, whole: bool) -> None:
        """The box of the glints since the last whole-frame search (reset by one); with
        ``focus`` the caller sets it (:meth:`focus_on`)."""
        if self.focus:
            return
        if len(det) == 0:
            if whole:
                self._box = None
            return
        v, u = det.v_px, det.u_px  # ordered by row
        box = (float(v[0]), float(v[-1]), float(u.min()), float(u.max()))
        if not whole and self._box is not None:
            old = self._box
            box = (min(box[0], old[0]), max(box[1], old[1]), min(box[2], old[2]),
                   max(box[3], old[3]))
        self._box = box


def window_margin_px(setup: Setup, eye_speed_deg_s: float = EYE_SPEED_MAX_DEG_S) -> int:
    """How far (px, rounded up) any glint of ``setup`` moves in one frame period while the
    eye turns at ``eye_speed_deg_s`` in any direction: :func:`glint_px_per_deg` times the angle
    turned in one frame. paper_sim: 3.6 px per degree, 10° per frame at 60 fps, 36 px."""
    if not eye_speed_deg_s > 0:
        raise ValueError(f"eye_speed_deg_s must be positive, got {eye_speed_deg_s!r}")
    return math.ceil(glint_px_per_deg(setup) * eye_speed_deg_s * setup.sensor.frame_period_s)


def glint_px_per_deg(setup: Setup) -> float:
    """The most any glint of ``setup`` moves on the image per degree of eye rotation (px/deg),
    in any direction: the largest singular value of each glint's 2 x 2 Jacobian in the Fick
    angles, by central differences of the closed-form projection (±0.5°) at primary gaze,
    the largest over the glints."""
    eye, h = setup.eye, math.radians(0.5)
    yaw = np.array([h, -h, 0.0, 0.0])
    pitch = np.array([0.0, 0.0, h, -h])
    g, visible = project_glints(setup.camera, eye.cornea_center(yaw, pitch), eye.cornea_radius_m,
                                setup.lights_world_m, cornea_axis=gaze_direction(yaw, pitch),
                                cap_cos_min=eye.cap_cos_min)
    seen = visible.all(axis=0)
    if not seen.any():
        raise ValueError(f"setup {setup.name!r}: no glint is visible at primary gaze")
    jac = np.stack([g[0] - g[1], g[2] - g[3]], axis=-1)[seen] / (2 * math.degrees(h))  # px/deg
    return float(np.linalg.norm(jac, ord=2, axis=(1, 2)).max())
