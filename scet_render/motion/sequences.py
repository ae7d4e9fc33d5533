"""Building trajectories: fixation, saccade and grid sequences, smooth pursuit, and
joining trajectories with main-sequence saccades.
"""

from __future__ import annotations

import numpy as np

from estimator.eye import Eye
from estimator.setup import Screen

from .saccades import FixationalNoise, SaccadeModel
from .trajectory import SAME_DIRECTION_RAD, SegmentKind, Trajectory, _noise_rows, _rows

# -- builders --------------------------------------------------------------------------------


def fixation_sequence(
    eye: Eye,
    targets_m,
    fixation_s,
    rng=None,
    *,
    noise: FixationalNoise | None = None,
    saccades: SaccadeModel = SaccadeModel(),
) -> Trajectory:
    """Fixations on each target in turn, joined by main-sequence saccades.

    Parameters
    ----------
    eye : Eye
        Gaze directions are taken from ``eye.rotation_center_m``.
    targets_m : (n, 3) float
        World targets, in front of the eye (direction with a negative z component).
    fixation_s : float or (n,) float
        Positive fixation durations in seconds.
    rng : numpy.random.Generator or int, optional
        Seed for the fixational noise; required when ``noise`` is given.
    noise : FixationalNoise, optional
        Fixational drift and tremor; None (the default) holds every target exactly.
    saccades : SaccadeModel
        Main-sequence constants and profile shape.

    Returns
    -------
    Trajectory
        Starts with the first fixation at t = 0 and ends with the last; repeated directions
        (closer than ``SAME_DIRECTION_RAD``) follow one another without a saccade.
    """
    c = eye.rotation_center_m
    targets, dirs = _targets(targets_m, c, "targets_m")
    n = targets.shape[0]
    fix_s = _durations(fixation_s, n, "fixation_s")
    gen = _noise_generator(rng, noise)

    pair_amp = _angle(dirs[:-1], dirs[1:])
    sac_dur, sac_ramp, _ = saccades.kinematics(np.where(pair_amp > 0, pair_amp, 1.0))
    rows = {
        "kind": np.full(2 * n - 1, SegmentKind.SACCADE, dtype=np.int8),
        "segment_duration_s": _interleave(fix_s, sac_dur),
        "start_direction": _interleave(dirs, dirs[:-1]),
        "plane_direction": _interleave(np.zeros_like(dirs), _tangent(dirs[:-1], dirs[1:])),
        "amplitude_rad": _interleave(np.zeros(n), pair_amp),
        "ramp_fraction": _interleave(np.zeros((n, 2)), sac_ramp),
        "from_target_m": _interleave(targets, targets[:-1]),
        "to_target_m": _interleave(targets, targets[1:]),
    }
    rows["kind"][0::2] = SegmentKind.FIXATION
    keep = np.ones(2 * n - 1, dtype=bool)
    keep[1::2] = pair_amp >= SAME_DIRECTION_RAD
    rows = {k: v[keep] for k, v in rows.items()}
    rows.update(_noise_rows(rows["kind"], gen, noise))
    return Trajectory(eye_center_m=c, **rows)


def saccade_sequence(
    eye: Eye,
    targets_m,
    rng,
    fixation_range_s: tuple[float, float] = (0.15, 0.4),
    *,
    noise: FixationalNoise | None = None,
    saccades: SaccadeModel = SaccadeModel(),
) -> Trajectory:
    """Fixations of uniformly random duration in ``fixation_range_s`` joined by saccades.

    ``rng`` (a ``numpy.random.Generator`` or an int seed) draws the durations first, then the
    fixational noise; the same seed gives identical trajectories. Other parameters as in
    :func:`fixation_sequence`.
    """
    lo, hi = (float(x) for x in fixation_range_s)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(
            f"fixation_range_s must be (lo, hi) with 0 < lo <= hi, got {fixation_range_s}")
    gen = _as_generator(rng)
    if gen is None:
        raise ValueError("saccade_sequence needs rng (a numpy.random.Generator or an int seed)")
    n = _targets(targets_m, eye.rotation_center_m, "targets_m")[0].shape[0]
    fix_s = gen.uniform(lo, hi, n)
    return fixation_sequence(eye, targets_m, fix_s, gen, noise=noise, saccades=saccades)


def grid_sequence(
    eye: Eye,
    screen: Screen,
    cols: int,
    rows: int,
    fixation_s,
    rng=None,
    *,
    margin: float = 0.5,
    noise: FixationalNoise | None = None,
    saccades: SaccadeModel = SaccadeModel(),
) -> Trajectory:
    """Fixations on ``screen.grid(cols, rows, margin)`` in its row-major order (top left first).

    ``fixation_s`` is a scalar or a (rows * cols,) array; the rest as in
    :func:`fixation_sequence`.
    """
    targets = screen.grid(cols, rows, margin)
    return fixation_sequence(eye, targets, fixation_s, rng, noise=noise, saccades=saccades)


def pursuit(eye: Eye, start_m, end_m, speed_deg_s: float) -> Trajectory:
    """Smooth pursuit from ``start_m`` to ``end_m`` (world points, (3,)) at constant speed.

    The gaze turns along the great circle between the two directions at ``speed_deg_s``
    (deg/s, > 0) from t = 0 to A / speed; there is no initiation ramp or catch-up saccade.
    :meth:`Trajectory.target_at` follows the point of the straight line from ``start_m`` to
    ``end_m`` under the gaze. Join it to fixations with :func:`concatenate`.
    """
    c = eye.rotation_center_m
    pts, dirs = _targets(np.stack([_point(start_m, "start_m"), _point(end_m, "end_m")]), c,
                         "start_m/end_m")
    speed = float(speed_deg_s)
    if not np.isfinite(speed) or speed <= 0:
        raise ValueError(f"speed_deg_s must be finite and > 0, got {speed_deg_s}")
    amp = float(_angle(dirs[0], dirs[1]))
    if amp < SAME_DIRECTION_RAD:
        raise ValueError("pursuit needs start_m and end_m in different directions from the eye")
    return Trajectory(
        kind=np.array([SegmentKind.PURSUIT]),
        segment_duration_s=np.array([amp / np.deg2rad(speed)]),
        start_direction=dirs[:1],
        plane_direction=_tangent(dirs[:1], dirs[1:]),
        amplitude_rad=np.array([amp]),
        ramp_fraction=np.zeros((1, 2)),
        from_target_m=pts[:1],
        to_target_m=pts[1:],
        eye_center_m=c,
    )


def concatenate(trajectories, *, saccades: SaccadeModel = SaccadeModel()) -> Trajectory:
    """Play trajectories one after the other.

    Where one ends looking elsewhere than the next starts, a main-sequence saccade joins them
    (from the last target of one to the first of the next). All must share one eye centre.
    """
    trajs = list(trajectories)
    if not trajs or not all(isinstance(t, Trajectory) for t in trajs):
        raise ValueError("concatenate needs a non-empty sequence of Trajectory")
    c = trajs[0].eye_center_m
    if any(not np.array_equal(t.eye_center_m, c) for t in trajs):
        raise ValueError("concatenate needs trajectories of the same eye (eye_center_m differs)")
    k = max(t.noise_amplitude_rad.shape[1] for t in trajs)
    parts = [_rows(trajs[0], k)]
    for prev, nxt in zip(trajs[:-1], trajs[1:]):
        d0, d1 = prev.final_direction, nxt.initial_direction
        amp = _angle(d0, d1)
        if amp >= SAME_DIRECTION_RAD:
            dur, ramp, _ = saccades.kinematics(np.array([amp]))
            parts.append({
                "kind": np.array([SegmentKind.SACCADE], dtype=np.int8),
                "segment_duration_s": dur,
                "start_direction": d0[None],
                "plane_direction": _tangent(d0[None], d1[None]),
                "amplitude_rad": np.array([amp]),
                "ramp_fraction": ramp,
                "from_target_m": prev.to_target_m[-1:],
                "to_target_m": nxt.from_target_m[:1],
                **_noise_rows(np.array([SegmentKind.SACCADE]), None, None, k),
            })
        parts.append(_rows(nxt, k))
    rows = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
    return Trajectory(eye_center_m=c, **rows)


# -- helpers ---------------------------------------------------------------------------------


def _as_generator(rng) -> np.random.Generator | None:
    if rng is None or isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise TypeError(
        f"rng must be a numpy.random.Generator, an int seed or None, got {type(rng).__name__}")


def _noise_generator(rng, noise):
    gen = _as_generator(rng)
    if noise is not None and gen is None:
        raise ValueError("fixational noise needs rng (a numpy.random.Generator or an int seed)")
    return gen


def _point(x, name):
    p = np.asarray(x, dtype=np.float64)
    if p.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {p.shape}")
    return p


def _targets(targets_m, center_m, name):
    """(n, 3) targets and their unit directions from the eye; rejects bad or rear targets."""
    t = np.asarray(targets_m, dtype=np.float64)
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] < 1:
        raise ValueError(f"{name} must have shape (n, 3) with n >= 1, got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{name} must be finite")
    v = t - center_m
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    behind = (v[:, 2] >= 0) | (norm[:, 0] == 0)
    if behind.any():
        bad = np.flatnonzero(behind).tolist()
        raise ValueError(f"{name}: targets {bad} are not in front of the "
                         "eye (the eye looks along -z, so a target needs z < the eye centre's z)")
    return t, v / norm


def _durations(x, n, name):
    d = np.asarray(x, dtype=np.float64)
    if d.shape not in ((), (n,)):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {d.shape}")
    d = np.broadcast_to(d, (n,)).copy()
    if not np.all(np.isfinite(d)) or np.any(d <= 0):
        raise ValueError(f"{name} must be finite and > 0, got {d}")
    return d


def _angle(a, b):
    """Angle in radians between unit vectors (..., 3), accurate for small and large angles."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _tangent(d0, d1):
    """(m, 3) unit vectors orthogonal to d0 in the plane of d0 and d1 (zeros if parallel)."""
    e = d1 - np.sum(d0 * d1, axis=-1, keepdims=True) * d0
    n = np.linalg.norm(e, axis=-1, keepdims=True)
    return np.divide(e, n, out=np.zeros_like(e), where=n > 0)


def _interleave(even, odd):
    out = np.empty((even.shape[0] + odd.shape[0],) + even.shape[1:], dtype=np.float64)
    out[0::2] = even
    out[1::2] = odd
    return out
