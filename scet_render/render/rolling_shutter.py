"""Physically based banded frames: a rolling-shutter camera under strobed lights (Mitsuba 3).

One frame (Sec. 2.3 of the SCET paper, Eqs. (2)-(8); :mod:`estimator.banding`):

* strobe pulse j lights rows with weight w_j(y) = |[E(y), R(y)] ∩ [s_j, s_j + Δs]| / Δs
  (:func:`estimator.banding.row_pulse_weights`); the eye pose is the trajectory's at the pulse
  centre t_j = s_j + Δs / 2 (the instant :func:`estimator.banding.row_strobe` stamps rows with),
  and the pulse is rendered only over the rows it lights;
* the ambient light is integrated over each row's own exposure window [E(y), R(y)] (Eq. (3)).
  The strobe renders sample it at the strobe instants for free (split channels: strobe light in
  R, ambient in G, see :mod:`scet_render.render.scene`); when the eye moves, ambient-only renders at
  extra instants (every Δ_clk / K, K chosen so that features move at most ``blur_step_px``
  between instants, up to ``max_ambient_instants``) make a saccade blur; each row averages the
  instants that rendered it with nearest-instant (midpoint) quadrature weights;
* the frame holds the exposure integral of radiance divided by the pulse width,
  ``radiance(y) = ∫_{E(y)}^{R(y)} L(y, t) dt / Δs = Σ_j w_j(y) L_j(y) + ∫ L_amb dt / Δs``:
  a row that collects a whole pulse reads the scene radiance under the strobe.

Row ranges are rendered with camera rays generated here (Mitsuba's own sensor maps film
positions to rays; the row offset and the seed are opaque Dr.Jit variables) inside a
``dr.freeze``-recorded function, so bands of any height and eye poses (scene parameter
updates) replay the same kernels without tracing or compiling. Film crops would compile once
per distinct crop (DESIGN.md). Under ``scalar_rgb`` rows are rendered with ``mi.render`` and a
cropped film. :meth:`BandedRenderer.render_frame_reference` renders every instant as a full
``mi.render`` frame and composites rows with the same weights: the slow reference.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from estimator.banding import exposure_start, readout_time, row_pulse_weights, strobe_instant
from estimator.eye import gaze_direction
from estimator.setup import Setup

from .backend import activate, is_jit_variant
from .layout import DEFAULT_AMBIENT_RADIANCE, SceneOptions
from .mnee_kernels import MneeKernels
from .scene import EyeScene, sensor_dict

#: Trajectory samples per strobe period used to measure the eye's angular speed in a frame.
SPEED_SAMPLES_PER_PERIOD = 16


def _band_rays(mi, sensor, row0, seed, lanes, spp: int, W: int, H: int):
    """Camera rays of a band's samples (``spp`` a pixel, rows from ``row0``, one lane each
    of ``lanes``): a seeded independent sampler, a jittered film position and a wavelength
    from it; returns (sampler, ray, weight)."""
    import drjit as dr

    n = dr.width(lanes)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    pixel = dr.arange(mi.UInt32, n) // spp
    film = mi.Point2f(mi.Float(pixel % W), mi.Float(pixel // W + row0))
    film += sampler.next_2d()
    wavelength = sampler.next_1d()
    ray, weight = sensor.sample_ray_differential(
        0.0, wavelength, film * mi.ScalarVector2f(1.0 / W, 1.0 / H), mi.Point2f(0.5, 0.5))
    return sampler, ray, weight


@dataclass(frozen=True, slots=True)
class FrameRender:
    """One rendered banded frame.

    Attributes
    ----------
    radiance : (H, W) float32
        Exposure-integrated near-IR radiance divided by the pulse width Δs (module docstring).
    pulse_indices : (P,) int64
        Global indices j of the pulses that light at least one visible row.
    pulse_times_s : (P,) float
        Pulse centres t_j = s_j + Δs / 2: the instants the eye pose was taken at.
    row_weights : (H, P) float
        w_j(y), the fraction of each pulse each row collects (Eqs. (2)-(3)).
    frame_index : int
    yaw_rad, pitch_rad : (P,) float
        Eye pose at each pulse.
    ambient_times_s : (M,) float
        Every instant the ambient light was sampled at (strobe instants included).
    lid_closure : (P,) float
        Upper lid closure of the trajectory's blinks at each pulse (zeros without blinks).
    """

    radiance: np.ndarray
    pulse_indices: np.ndarray
    pulse_times_s: np.ndarray
    row_weights: np.ndarray
    frame_index: int
    yaw_rad: np.ndarray
    pitch_rad: np.ndarray
    ambient_times_s: np.ndarray
    lid_closure: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class FramePlan:
    """What to render for one frame: one slice per instant, in time order.

    Attributes
    ----------
    times_s : (M,) float
        Slice instants.
    rows : (M, 2) int
        Half-open visible row range [start, stop) each slice renders.
    pulse_column : (M,) int
        Column of ``row_weights`` a strobe slice belongs to; -1 for ambient-only slices.
    ambient_weights_s : (H, M) float
        Quadrature weights (seconds) of each slice's ambient image in each row; every row's
        weights sum to the exposure Δe.
    pulse_indices, pulse_times_s, row_weights
        As in :class:`FrameRender`.
    instants_per_period : int
        K, ambient instants per strobe period.
    """

    times_s: np.ndarray
    rows: np.ndarray
    pulse_column: np.ndarray
    ambient_weights_s: np.ndarray
    pulse_indices: np.ndarray
    pulse_times_s: np.ndarray
    row_weights: np.ndarray
    instants_per_period: int


def _rows_containing(t_s: float, E: np.ndarray, R: np.ndarray) -> tuple[int, int]:
    """[start, stop) of the rows whose exposure window [E(y), R(y)] contains t (E, R increase)."""
    start = int(np.searchsorted(R, t_s, side="left"))
    stop = int(np.searchsorted(E, t_s, side="right"))
    return start, max(start, stop)


def _midpoint_weights(times_s, covered, E, R) -> np.ndarray:
    """(H, M) nearest-instant quadrature of each row's window over the instants covering it.

    Row y's instants (sorted ``times_s`` where ``covered[y]``) split the time axis at their
    midpoints; each gets the length of its cell inside [E(y), R(y)], so a row's weights sum to
    its exposure, and an instant just outside the window still stands for the nearby part.
    """
    H, M = covered.shape
    k = np.arange(M)
    before = np.maximum.accumulate(np.where(covered, k, -1), axis=1)
    after = np.minimum.accumulate(np.where(covered, k, M)[:, ::-1], axis=1)[:, ::-1]
    prev = np.concatenate([np.full((H, 1), -1), before[:, :-1]], axis=1)
    nxt = np.concatenate([after[:, 1:], np.full((H, 1), M)], axis=1)
    t = np.concatenate([[np.nan], times_s, [np.nan]])  # index -1 -> t[0], M -> t[M + 1]
    lo = np.where(prev >= 0, 0.5 * (t[prev + 1] + times_s), -np.inf)
    hi = np.where(nxt < M, 0.5 * (t[nxt + 1] + times_s), np.inf)
    w = np.minimum(hi, R[:, None]) - np.maximum(lo, E[:, None])
    return np.where(covered, np.maximum(w, 0.0), 0.0)


def motion_instants(setup: Setup, trajectory, t0_s: float, t1_s: float, *,
                    blur_step_px: float, max_instants: int) -> int:
    """Ambient instants per strobe period K so that the eye surface moves <= ``blur_step_px``.

    A point of the eyeball (the sclera radius, ~11 mm from the rotation centre) seen from the
    camera moves by about fx * radius / distance pixels per radian of eye rotation.
    """
    period = setup.strobe.period_s
    n = max(2, math.ceil((t1_s - t0_s) / period * SPEED_SAMPLES_PER_PERIOD) + 1)
    yaw, pitch = trajectory.angles_at(np.linspace(t0_s, t1_s, n))
    g = gaze_direction(yaw, pitch)
    step = np.arccos(np.clip(np.einsum("ij,ij->i", g[1:], g[:-1]), -1.0, 1.0))
    rad_per_period = float(step.max()) * (n - 1) * period / (t1_s - t0_s)
    eye = setup.eye
    radius = math.hypot(eye.cornea_offset_m + eye.cornea_radius_m - eye.limbus_depth_m,
                        eye.limbus_radius_m)
    distance = float(np.linalg.norm(setup.camera.position_m - eye.rotation_center_m))
    blur_px = rad_per_period * setup.camera.fx_px * radius / distance
    return int(min(max(1, math.ceil(blur_px / blur_step_px - 1e-9)), max_instants))


def plan_frame(setup: Setup, trajectory, frame_index: int, *, blur_step_px: float = 2.0,
               max_ambient_instants: int = 8, ambient: bool = True) -> FramePlan:
    """The slices (instants, rows, weights) of one banded frame; see the module docstring.

    With ``ambient=False`` (no ambient light in the scene) only the strobe slices are planned.
    """
    sensor, strobe = setup.sensor, setup.strobe
    N = sensor.visible_lines
    j, s, w = row_pulse_weights(sensor, strobe, frame_index)
    lit = w.max(axis=0) > 0
    j, s, w = j[lit], s[lit], w[:, lit]
    t_pulse = strobe_instant(s, strobe.pulse_s)
    rows = np.arange(N, dtype=np.float64)
    E, R = exposure_start(rows, sensor, frame_index), readout_time(rows, sensor, frame_index)
    K = 1 if not ambient else motion_instants(
        setup, trajectory, float(E[0]), float(R[-1]), blur_step_px=blur_step_px,
        max_instants=max_ambient_instants)
    slices = []  # (time, start, stop, column)
    for c in range(j.size):
        y = np.flatnonzero(w[:, c] > 0)
        slices.append((float(t_pulse[c]), int(y[0]), int(y[-1]) + 1, c))
    if K > 1:
        # A grid of spacing Δ_clk / K through the strobe instants (they are its multiples of K).
        delta = strobe.period_s / K
        t_ref = float(t_pulse[0]) if j.size else float(E[0]) + 0.5 * delta
        m = np.arange(math.floor((E[0] - t_ref) / delta), math.ceil((R[-1] - t_ref) / delta) + 1)
        for step in m[(m % K != 0) | (j.size == 0)]:
            t = t_ref + float(step) * delta
            start, stop = _rows_containing(t, E, R)
            if stop > start:
                slices.append((t, start, stop, -1))
    covered = np.zeros(N, dtype=bool)
    for _, start, stop, _ in slices:
        covered[start:stop] = True
    # Rows no pulse lights (dark gaps of a slow strobe): ambient-only slices, each at an instant
    # inside the windows of a run of at most S Δe / Δt rows.
    run_rows = max(1, int(sensor.exposure_s / sensor.line_time_s))
    y = 0 if ambient else N
    while y < N:
        if covered[y]:
            y += 1
            continue
        stop = y
        while stop < N and not covered[stop] and stop - y < run_rows:
            stop += 1
        slices.append((0.5 * (float(E[stop - 1]) + float(R[y])), y, stop, -1))
        covered[y:stop] = True
        y = stop
    slices.sort(key=lambda x: x[0])
    times = np.array([x[0] for x in slices])
    row_range = np.array([[x[1], x[2]] for x in slices], dtype=np.int64).reshape(-1, 2)
    cover = np.zeros((N, len(slices)), dtype=bool)
    for k, (start, stop) in enumerate(row_range):
        cover[start:stop, k] = True
    return FramePlan(times, row_range, np.array([x[3] for x in slices], dtype=np.int64),
                     _midpoint_weights(times, cover, E, R), j, t_pulse, w, K)


def _slice_seed(seed: int, frame_index: int, k: int) -> int:
    return int(np.random.SeedSequence([seed, frame_index & 0xFFFFFFFF, k]).generate_state(1)[0])


class BandedRenderer:
    """Render banded frames of a Setup with Mitsuba 3 (see the module docstring).

    Parameters
    ----------
    setup : Setup
    variant : str, optional
        Mitsuba variant (:func:`scet_render.render.backend.choose_variant`); default: the best found.
    spp : int
        Samples per pixel of the strobe renders.
    cornea : {"dielectric", "plain_dielectric", "conductor"}
        Corneal material (:class:`scet_render.render.scene.SceneOptions`).
    eyelid_openness : float or None
        1 = fully open (the cornea is never covered for gazes at the screen), 0 = closed,
        None = no eyelids. A Setup with ``eyelids`` (lids that follow the eye, and blink with
        the trajectory's ``blinks``) renders those instead, at any value but None.
    ambient : float
        Ambient environment radiance (W sr^-1 m^-2), 0 for none.
    seed : int
        Base seed; the same seed gives byte-identical frames.
    ambient_spp : int, optional
        Samples per pixel of ambient-only renders (default max(1, spp // 16)). The ambient is
        dim (a few % of the strobe-lit radiance), so its noise matters little.
    blur_step_px, max_ambient_instants
        Motion-blur sampling of the ambient light (:func:`plan_frame`): an ambient instant
        every ``blur_step_px`` of eyeball motion, at most ``max_ambient_instants`` per strobe
        period. The default 2 px gives K = 2 in the paper's saccades (1300 px focal length,
        ~3 px of blur per exposure), at ~10 % of a frame's time.
    options : SceneOptions, optional
        Full scene options; ``cornea``, ``eyelid_openness`` and ``ambient`` override its fields.
    """

    def __init__(self, setup: Setup, *, variant: str | None = None, spp: int = 16,
                 cornea: str = "dielectric", eyelid_openness: float | None = 1.0,
                 ambient: float = DEFAULT_AMBIENT_RADIANCE, seed: int = 0,
                 ambient_spp: int | None = None, blur_step_px: float = 2.0,
                 max_ambient_instants: int = 8, options: SceneOptions | None = None):
        for name, v in (("spp", spp), ("max_ambient_instants", max_ambient_instants)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        if ambient_spp is not None and (not isinstance(ambient_spp, (int, np.integer))
                                        or ambient_spp < 1):
            raise ValueError(f"ambient_spp must be an integer >= 1, got {ambient_spp!r}")
        if not (isinstance(seed, (int, np.integer)) and 0 <= seed < 2**32):
            raise ValueError(f"seed must be an integer in [0, 2**32), got {seed!r}")
        if not (math.isfinite(blur_step_px) and blur_step_px > 0):
            raise ValueError(f"blur_step_px must be finite and > 0, got {blur_step_px!r}")
        base = options if options is not None else SceneOptions()
        self.options = dataclasses.replace(base, cornea=cornea, eyelid_openness=eyelid_openness,
                                           ambient_radiance=float(ambient), channels="split")
        self.setup, self.spp, self.seed = setup, int(spp), int(seed)
        self.ambient_spp = int(ambient_spp) if ambient_spp is not None else max(1, spp // 16)
        self.blur_step_px, self.max_ambient_instants = float(blur_step_px), max_ambient_instants
        self.mi = activate(variant)
        self.variant = self.mi.variant()
        self.eye_scene = EyeScene(setup, self.options, spp=self.spp, mi=self.mi)
        self._kernels = {}
        self._crop_sensors = {}
        self._mnee = MneeKernels(self.mi, setup, self.options, _band_rays)

    # ------------------------------------------------------------------ row rendering

    def _jit_kernel(self, spp: int, n_rows: int):
        # One frozen function per (spp, rows): dr.width() is a literal of a recording, so a
        # recording replays only at its own width. Band heights take a handful of values.
        if (spp, n_rows) not in self._kernels:
            import drjit as dr

            mi = self.mi
            W, H = self.setup.camera.width_px, self.setup.camera.height_px

            def render(scene, sensor, integrator, row0, seed, lanes):
                sampler, ray, weight = _band_rays(mi, sensor, row0, seed, lanes, spp, W, H)
                L, _, _ = integrator.sample(scene, sampler, ray, None, True)
                L = L * weight
                dr.eval(L)  # one path-tracing kernel, then a block reduction per channel
                return dr.block_sum(L, spp) * (1.0 / spp)

            # A mesh cornea gets new vertex buffers at every pose, and Dr.Jit 1.5 replays
            # frozen kernels with the old ones (no glints: measured); it is traced each time.
            frozen = self.options.cornea_geometry == "sphere"
            self._kernels[spp, n_rows] = dr.freeze(render) if frozen else render
        return self._kernels[spp, n_rows]

    def _render_rows_now(self, row_start: int, row_stop: int, spp: int, seed: int,
                         strobe: bool = True):
        """(rows, W, 3) float32 for the current pose; ``strobe=False``: an ambient-only
        instant, whose strobe channel is not used (MNEE is skipped)."""
        mi = self.mi
        W = self.setup.camera.width_px
        n_rows = row_stop - row_start
        if is_jit_variant(self.variant):
            import drjit as dr

            es = self.eye_scene
            out = self._jit_kernel(spp, n_rows)(es.scene, es.sensor, es.integrator,
                                        dr.opaque(mi.UInt32, row_start),
                                        dr.opaque(mi.UInt32, seed),
                                        dr.zeros(mi.UInt32, n_rows * W * spp))
            img = np.asarray(out, dtype=np.float32).T.reshape(n_rows, W, 3)
            if es.mnee_enabled and strobe:
                # Its own sample stream: the seed's complement (seeds are < 2**32).
                img[..., 0] += self._mnee.rows(es, row_start, n_rows, spp,
                                               (~seed) & 0xFFFFFFFF)
            return img
        key = (row_start, row_stop)
        if key not in self._crop_sensors:
            d = sensor_dict(self.setup.camera, spp)
            d["film"] = {**d["film"], "crop_offset_x": 0, "crop_offset_y": int(row_start),
                         "crop_width": W, "crop_height": int(n_rows)}
            d["to_world"] = mi.ScalarTransform4f(d["to_world"])
            self._crop_sensors[key] = mi.load_dict(d)
        img = mi.render(self.eye_scene.scene, sensor=self._crop_sensors[key], spp=spp, seed=seed,
                        integrator=self.eye_scene.render_integrator)
        return np.asarray(img, dtype=np.float32).reshape(n_rows, W, 3)

    def render_rows(self, yaw_rad: float, pitch_rad: float, row_start: int = 0,
                    row_stop: int | None = None, *, spp: int | None = None,
                    seed: int = 0, closure: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Strobe-lit and ambient radiance of image rows [row_start, row_stop) at one eye pose
        (and upper lid ``closure``, for lids that follow the eye: :meth:`EyeScene.set_pose`).

        Returns
        -------
        strobe : (rows, W) float32
            Radiance with every strobe light on (no ambient).
        ambient : (rows, W) float32
            Radiance under the ambient environment alone.
        """
        H = self.setup.camera.height_px
        row_stop = H if row_stop is None else row_stop
        if not (0 <= row_start < row_stop <= H):
            raise ValueError(f"need 0 <= row_start < row_stop <= {H}, got [{row_start}, "
                             f"{row_stop})")
        if not (isinstance(seed, (int, np.integer)) and 0 <= seed < 2**32):
            raise ValueError(f"seed must be an integer in [0, 2**32), got {seed!r}")
        if spp is not None and (not isinstance(spp, (int, np.integer)) or spp < 1):
            raise ValueError(f"spp must be an integer >= 1, got {spp!r}")
        self.eye_scene.set_pose(yaw_rad, pitch_rad, closure)
        img = self._render_rows_now(int(row_start), int(row_stop), int(spp or self.spp),
                                   int(seed))
        return img[..., 0], img[..., 1]

    def render_global(self, yaw_rad: float, pitch_rad: float, *, seed: int = 0,
                      closure: float = 0.0) -> np.ndarray:
        """(H, W) float32 global-shutter frame: one pulse and Δe of ambient, all rows at once."""
        strobe, ambient = self.render_rows(yaw_rad, pitch_rad, seed=seed, closure=closure)
        ratio = self.setup.sensor.exposure_s / self.setup.strobe.pulse_s
        return (strobe + np.float32(ratio) * ambient).astype(np.float32)

    # ------------------------------------------------------------------ frames

    def plan(self, trajectory, frame_index: int) -> FramePlan:
        """The :class:`FramePlan` of a frame of ``trajectory``."""
        return plan_frame(self.setup, trajectory, frame_index, blur_step_px=self.blur_step_px,
                          max_ambient_instants=self.max_ambient_instants,
                          ambient=self.options.ambient_radiance > 0)

    def _compose(self, trajectory, frame_index: int, full_frames: bool) -> FrameRender:
        plan = self.plan(trajectory, frame_index)
        yaw, pitch = trajectory.angles_at(plan.times_s)
        yaw, pitch = np.atleast_1d(yaw), np.atleast_1d(pitch)
        closure = getattr(trajectory, "lid_closure_at", None)
        closure = (np.zeros(yaw.shape) if closure is None
                   else np.atleast_1d(closure(plan.times_s)))
        H = self.setup.camera.height_px
        radiance = np.zeros((H, self.setup.camera.width_px))
        inv_pulse = 1.0 / self.setup.strobe.pulse_s
        for k in range(plan.times_s.size):
            start, stop = (int(v) for v in plan.rows[k])
            col = int(plan.pulse_column[k])
            spp = self.spp if col >= 0 else self.ambient_spp
            seed = _slice_seed(self.seed, frame_index, k)
            self.eye_scene.set_pose(yaw[k], pitch[k], closure[k])
            if full_frames:
                img = self.mi.render(self.eye_scene.scene, spp=spp, seed=seed,
                                     integrator=self.eye_scene.render_integrator)
                img = np.asarray(img, dtype=np.float32)[start:stop]
            else:
                img = self._render_rows_now(start, stop, spp, seed, strobe=col >= 0)
            if col >= 0:
                radiance[start:stop] += plan.row_weights[start:stop, col, None] * img[..., 0]
            radiance[start:stop] += (plan.ambient_weights_s[start:stop, k, None] * inv_pulse
                                     * img[..., 1])
        strobe_k = np.flatnonzero(plan.pulse_column >= 0)
        order = np.argsort(plan.pulse_column[strobe_k])
        return FrameRender(radiance.astype(np.float32), plan.pulse_indices, plan.pulse_times_s,
                           plan.row_weights, int(frame_index), yaw[strobe_k][order],
                           pitch[strobe_k][order], plan.times_s, closure[strobe_k][order])

    def render_frame(self, trajectory, frame_index: int) -> FrameRender:
        """Render frame ``frame_index`` of an eye ``trajectory`` (``angles_at(t)``), band by band.

        Each strobe is rendered only over the rows it lights, at the pose of its instant.
        """
        return self._compose(trajectory, frame_index, full_frames=False)

    def render_frame_reference(self, trajectory, frame_index: int) -> FrameRender:
        """The slow reference: every instant rendered as a full frame (``mi.render``), then
        composited row by row with the same weights as :meth:`render_frame`."""
        return self._compose(trajectory, frame_index, full_frames=True)
