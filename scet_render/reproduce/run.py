"""Running the reproduction: every experiment, the summaries, and the report.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from estimator.metrics import summarize_errors

from .common import (
    NOISE_PX,
    RIG_ROTATION_AXIS,
    RIG_ROTATION_DEG,
    RIG_TRANSLATION_M,
    TRANSLATION_HALF_M,
    ReproductionConfig,
    config_for,
    make_context,
    stats,
    trial_rng,
)
from .paper import (
    TRANSLATION_METHODS,
    TRANSLATION_PLANES,
    _mean,
    calibration_trial,
    solver_check,
    translation_trial,
)

# --------------------------------------------------------------------------- orchestration


_WORKER_CONTEXT = None


def _context(ctx):
    """``ctx``, or this process's own (a Ray worker builds it once, on its first task)."""
    global _WORKER_CONTEXT
    if ctx is not None:
        return ctx
    if _WORKER_CONTEXT is None:
        _WORKER_CONTEXT = make_context()
    return _WORKER_CONTEXT


def _calibration_task(ctx, seed, k, t, ef, with_gaze):
    return calibration_trial(_context(ctx), ef, trial_rng(seed, 5, k, t), with_gaze=with_gaze)


def _solver_task(ctx, cfg):
    return solver_check(_context(ctx), cfg)


def _translation_task(ctx, seed, t, steps):
    return translation_trial(_context(ctx), steps, trial_rng(seed, 7, t))


def _band_task(ctx, seed, t, counts):
    from .bands import band_trial

    return band_trial(_context(ctx), counts, trial_rng(seed, 9, t))


def run_experiments(cfg: ReproductionConfig, progress=None, pool=None) -> dict:
    """Run every experiment of ``cfg``; returns plain numbers and arrays (see
    :mod:`scet_render.reproduce.report` for how they are read).

    ``pool`` (:class:`scet_render.cluster.TaskPool`) runs the trials as Ray tasks; each trial
    draws from its own generator (:func:`trial_rng`), so the numbers are those of the serial
    run (None) whatever the worker count.
    """
    from ..cluster import TaskPool
    from .bands import summarize_bands

    pool = pool if pool is not None else TaskPool()
    ctx = make_context()
    shipped = None if pool.distributed else ctx  # Ray workers build their own
    n_levels = len(cfg.noise_levels_px)
    total = n_levels * cfg.calibration_trials + 1 + cfg.translation_trials + cfg.band_trials
    done = 0

    def ticker(labels):
        def tick(i):
            nonlocal done
            done += 1
            if progress is not None:
                progress(done, total, labels[i])
        return tick

    tasks, labels = [], []
    for k, ef in enumerate(cfg.noise_levels_px):
        for t in range(cfg.calibration_trials):
            tasks.append((shipped, cfg.seed, k, t, ef, ef == NOISE_PX and t < cfg.gaze_trials))
            labels.append(f"Fig. 5 / Sec. 3.2: e_f = {ef:.2f} px, trial {t + 1} of {cfg.calibration_trials}")
    results = pool.map(_calibration_task, tasks, ticker(labels))
    fig5_rows, gaze = [], []
    for k in range(n_levels):
        level = results[k * cfg.calibration_trials:(k + 1) * cfg.calibration_trials]
        fig5_rows.append([row for row, _ in level])
        gaze.extend(g for _, g in level if g is not None)
    check, = pool.map(_solver_task, [(shipped, cfg)], ticker(["solver check: the paper's TRF against our LM"]))
    trans = pool.map(_translation_task,
                     [(shipped, cfg.seed, t, cfg.translation_steps) for t in range(cfg.translation_trials)],
                     ticker([f"Fig. 7 and 8: trial {t + 1} of {cfg.translation_trials}"
                             for t in range(cfg.translation_trials)]))
    bands = pool.map(_band_task, [(shipped, cfg.seed, t, cfg.band_counts) for t in range(cfg.band_trials)],
                     ticker([f"Fig. 9: trial {t + 1} of {cfg.band_trials}" for t in range(cfg.band_trials)]))
    return {
        "config": dataclasses.asdict(cfg),
        "rig": {"rotation_deg": RIG_ROTATION_DEG, "rotation_axis": tuple(float(v) for v in RIG_ROTATION_AXIS),
                "translation_mm": tuple(float(v) * 1e3 for v in RIG_TRANSLATION_M),
                "pivot_mm": tuple(round(float(v) * 1e3, 3) for v in ctx.grid.lights_world_m.mean(axis=0))},
        "fig5": _summarize_fig5(cfg, fig5_rows),
        "sec32": _summarize_gaze(ctx, gaze),
        "solver_check": check,
        "translation": _summarize_translation(cfg, trans),
        "bands": summarize_bands(cfg.band_counts, bands),
        "targets": {"grid": ctx.targets_grid, "calib9": ctx.targets9, "calib25": ctx.targets25},
        "screen": {"x_range_m": ctx.arc.screen.x_range_m, "y_range_m": ctx.arc.screen.y_range_m},
    }


def _summarize_fig5(cfg, rows_per_level) -> dict:
    keys = list(rows_per_level[0][0])
    return {"noise_px": list(cfg.noise_levels_px),
            "series": {k: [stats([r[k] for r in rows]) for rows in rows_per_level] for k in keys}}


def _summarize_gaze(ctx, trials) -> dict:
    """Per method: the paper's statistic (mean and SD over the 360 targets of a trial, averaged
    over trials), the share of failed estimates, and the per-target mean error (Fig. 6)."""
    if not trials:
        return {"trials": 0, "methods": {}, "ranks": {}}
    methods = {}
    for name in trials[0]["errors"]:
        E = np.stack([t["errors"][name] for t in trials])  # (trials, 360)
        per = [summarize_errors(e) for e in E]
        finite = np.isfinite(E)
        counts = finite.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            per_target = np.where(counts > 0, np.where(finite, E, 0.0).sum(axis=0) / np.maximum(counts, 1), np.nan)
        methods[name] = {"mean": _mean([p.mean_deg for p in per]), "sd": _mean([p.sd_deg for p in per]),
                         "sd_of_trial_means": stats([p.mean_deg for p in per])["sd"],
                         "failed_share": float(1 - finite.mean()), "per_target": per_target}
    ranks = {k: stats([t["ranks"][k] for t in trials]) for k in trials[0]["ranks"]}
    return {"trials": len(trials), "methods": methods, "ranks": ranks}


def _summarize_translation(cfg, trials) -> dict:
    out = {"steps": list(cfg.translation_steps), "half_mm": TRANSLATION_HALF_M * 1e3,
           "da_rank": stats([t["da_rank"] for t in trials])}
    for plane in TRANSLATION_PLANES:
        out[plane] = {m: [stats([t[plane][m][i] for t in trials])["mean"] for i in range(len(cfg.translation_steps))]
                      for m in TRANSLATION_METHODS}
    return out


def run_reproduction(out_dir: Path, *, quick: bool, seed: int = 0, progress=None,
                     workers: int | None = None, address: str | None = None) -> Path:
    """Run every experiment and write ``out_dir/paper-reproduction.md`` and
    ``out_dir/figures/*.png``; returns the report's path. Deterministic for a seed.

    Parameters
    ----------
    out_dir : Path
    quick : bool
        A few trials and levels (under a minute on two cores) instead of the paper's protocol
        (about ten minutes).
    seed : int
    progress : callable, optional
        ``progress(done, total, label)`` after each trial.
    workers : int, optional
        Run the trials as tasks of a local Ray with this many CPUs (:mod:`scet_render.cluster`).
    address : str, optional
        Run them on an existing Ray cluster instead. Either way the report is the serial run's.
    """
    from ..cluster import task_pool
    from .report import write_report

    cfg = config_for(quick, seed)
    with task_pool(workers, address) as pool:
        results = run_experiments(cfg, progress, pool)
    return write_report(Path(out_dir), results)
