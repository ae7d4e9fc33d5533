"""``scet score``: gaze samples (``samples.csv`` of ``scet track``) against a rendered
dataset's ground truth, with the metrics of ``scet validate``.

Each sample is keyed by its frame and strobe to the dataset's label of that strobe
(``labels.jsonl``): the true gaze point is the screen point of the labelled eye rotation (the
optical axis from the eye's rotation centre, as in :mod:`scet_render.validate.run`), the error
the angle at the rotation centre (:func:`estimator.metrics.angular_error_deg`), and accuracy and
robustness those of the paper (:func:`estimator.metrics.summarize_errors`: mean, SD, share under
5 deg). Rows per samples file (one per method) and band position: the band's centre row in the
top, middle or bottom third of the visible rows, where the paper expects lids and lashes to
hurt (Sec. 3.5). Reason codes are counted per file. A sample with no label (a frame or strobe
the dataset does not have) is an error: the files do not belong together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.eye import gaze_direction
from estimator.folders import read_samples_csv
from estimator.formats import atomic_file, atomic_write
from estimator.gaze import screen_intersection
from estimator.metrics import angular_error_deg, summarize_errors
from estimator.scene import parse_scene
from estimator.setup import Setup

from ..dataset import DatasetError, iter_labels
from ..dataset.manifest import read_manifest

#: Band positions: thirds of the visible rows, by the band's centre row.
POSITIONS = ("top", "middle", "bottom")


def true_gaze_points(setup: Setup, labels) -> np.ndarray:
    """(m, 3) screen points of the labelled eye rotations: the optical axis from the rotation
    centre through the screen (NaN where it misses the screen plane)."""
    yaw = np.array([lb.yaw_rad for lb in labels])
    pitch = np.array([lb.pitch_rad for lb in labels])
    p, _ = screen_intersection(setup.eye.rotation_center_m, gaze_direction(yaw, pitch),
                               setup.screen.z_m)
    return p


def band_position(label, visible_lines: int) -> str:
    """``"top"``, ``"middle"`` or ``"bottom"``: the third of the visible rows holding the
    centre of the label's band."""
    centre = 0.5 * (label.first_row + label.last_row)
    return POSITIONS[min(2, max(0, int(3 * centre // visible_lines)))]


def error_statistics(errors_deg) -> tuple:
    """(samples, valid share, mean, SD, median, 95th percentile, robustness) of (m,) angular
    errors in degrees, NaN where a sample failed: the columns of the validation's and the
    score's tables (:func:`estimator.metrics.summarize_errors` and the order statistics)."""
    err = np.asarray(errors_deg, dtype=np.float64)
    s = summarize_errors(err)
    fin = err[np.isfinite(err)]
    return (s.n, 1.0 - s.n_nan / max(s.n, 1), s.mean_deg, s.sd_deg,
            float(np.median(fin)) if fin.size else math.nan,
            float(np.percentile(fin, 95)) if fin.size else math.nan, s.robustness)


@dataclass(frozen=True, slots=True)
class ScoreRow:
    """Accuracy and robustness of one method at one band position (``"all"``: every band)."""

    method: str
    position: str
    samples: int
    valid: float
    mean_deg: float
    sd_deg: float
    median_deg: float
    p95_deg: float
    robustness: float

    @classmethod
    def from_errors(cls, method: str, position: str, err) -> "ScoreRow":
        return cls(method, position, *error_statistics(err))


@dataclass(frozen=True, slots=True)
class Score:
    """The result of :func:`score_samples`.

    Attributes
    ----------
    rows : list of ScoreRow
        Per method: all bands, then each band position.
    reasons : dict[str, dict[str, int]]
        Per method, the count of each reason code (``ok`` included).
    errors : dict[str, ndarray]
        Per method, every sample's error (deg, NaN where not estimated).
    positions : dict[str, list[str]]
        Per method, every sample's band position.
    dataset : Path
    """

    rows: list
    reasons: dict
    errors: dict
    positions: dict
    dataset: Path


def _method_name(path: Path) -> str:
    return path.stem.removeprefix("samples_").removeprefix("samples") or path.stem


def score_samples(samples_paths, dataset, *, setup: Setup | None = None,
                  names=None) -> Score:
    """Score samples files against a rendered dataset.

    Parameters
    ----------
    samples_paths : path or list of paths
        ``samples.csv`` files (``scet-samples`` versions 1-2), one per method or run.
    dataset : path
        The dataset folder they were tracked from (``manifest.json``, ``labels.jsonl``).
    setup : Setup, optional
        The eye and screen the labels refer to; default: the scene in the dataset's manifest.
    names : list of str, optional
        A name per file for the tables (default: the file name without ``samples_``).

    Raises
    ------
    DatasetError
        ``dataset`` is not a finished SCET dataset.
    ValueError
        A samples file cannot be read, or names a frame and strobe the dataset has no label for.
    """
    dataset = Path(dataset)
    paths = [Path(samples_paths)] if isinstance(samples_paths, (str, Path)) else [
        Path(p) for p in samples_paths]
    if not paths:
        raise ValueError("no samples file to score")
    manifest = read_manifest(dataset)
    if setup is None:
        try:
            setup = parse_scene(manifest["scene"]["toml"], source=f"{dataset}/manifest.json")
        except (KeyError, TypeError):
            raise DatasetError(f"{dataset}/manifest.json: key 'scene.toml' missing") from None
    try:
        height = int(manifest["image"]["height_px"])
    except (KeyError, TypeError, ValueError):
        raise DatasetError(f"{dataset}/manifest.json: key 'image.height_px' missing") from None
    labels = {(lb.frame, lb.strobe): lb for lb in iter_labels(dataset)}
    names = list(names) if names is not None else [None] * len(paths)
    if len(names) != len(paths):
        raise ValueError(f"{len(names)} names for {len(paths)} samples files")
    rows, reasons, errors, positions = [], {}, {}, {}
    for path, name in zip(paths, names):
        samples = read_samples_csv(path)
        method = name or _method_name(path)
        if method in errors:
            method = f"{method} ({path.name})"
        keyed, est = [], []
        for i, s in enumerate(samples, start=3):  # line 1: "# scet-samples N", 2: header
            try:
                key = (int(s["frame"]), int(s["strobe"]))
                xy = (float(s["screen_x_m"]), float(s["screen_y_m"]))
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"{path}, line {i}: malformed sample row") from None
            if key not in labels:
                raise ValueError(f"{path}, line {i}: frame {key[0]} strobe {key[1]} has no label in "
                                 f"{dataset}/labels.jsonl: the samples were not tracked from it")
            keyed.append(labels[key])
            est.append([xy[0], xy[1], setup.screen.z_m])
        truth = true_gaze_points(setup, keyed) if keyed else np.zeros((0, 3))
        err = (angular_error_deg(np.array(est), truth, setup.eye.rotation_center_m)
               if keyed else np.zeros(0))
        pos = [band_position(lb, height) for lb in keyed]
        errors[method], positions[method] = err, pos
        rows.append(ScoreRow.from_errors(method, "all", err))
        for p in POSITIONS:
            rows.append(ScoreRow.from_errors(method, p, err[np.array(pos, dtype=object) == p]
                                             if pos else np.zeros(0)))
        counts = {}
        for s in samples:
            counts[s.get("reason", "")] = counts.get(s.get("reason", ""), 0) + 1
        reasons[method] = dict(sorted(counts.items()))
    return Score(rows, reasons, errors, positions, dataset)


def _cell(x, fmt: str) -> str:
    return "-" if not math.isfinite(x) else format(x, fmt)


def score_table(score: Score) -> str:
    """The accuracy table as markdown."""
    out = ["| method | band position | samples | valid | mean (SD) deg | median deg | p95 deg | "
           "robustness (<5 deg) |", "|---|---|---|---|---|---|---|---|"]
    for r in score.rows:
        out.append(f"| {r.method} | {r.position} | {r.samples} | {r.valid:.1%} | "
                   f"{_cell(r.mean_deg, '.3f')} ({_cell(r.sd_deg, '.3f')}) | "
                   f"{_cell(r.median_deg, '.3f')} | {_cell(r.p95_deg, '.3f')} | {r.robustness:.1%} |")
    return "\n".join(out).replace("%", " %")


def reasons_table(score: Score) -> str:
    """Reason codes per method as markdown."""
    codes = sorted({c for counts in score.reasons.values() for c in counts})
    out = ["| reason | " + " | ".join(score.reasons) + " |", "|---|" + "---|" * len(score.reasons)]
    for c in codes:
        out.append(f"| {c} | " + " | ".join(str(counts.get(c, 0)) for counts in score.reasons.values())
                   + " |")
    return "\n".join(out)


def write_score_report(score: Score, path, *, plots: bool = True) -> Path:
    """Write the tables (and, with ``plots``, a figure of the errors per band position beside
    it, ``<name>_errors.png``) as markdown to ``path``; returns the path."""
    path = Path(path)
    parts = [f"# Gaze samples against {score.dataset}", "",
             "Errors are angles at the eye's rotation centre between the estimated and the true "
             "screen point of each strobe sample (`scet score`, the metrics of `scet validate`).",
             "", score_table(score), "", "Reason codes:", "", reasons_table(score), ""]
    if plots:
        fig = path.with_name(path.stem + "_errors.png")
        _plot(score, fig)
        parts += [f"![errors per band position]({fig.name})", ""]
    return atomic_write(path, "\n".join(parts))


def _plot(score: Score, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 3.2), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    methods = list(score.errors)
    width = 0.8 / max(1, len(methods))
    for k, m in enumerate(methods):
        err, pos = score.errors[m], np.array(score.positions[m], dtype=object)
        data = [err[(pos == p) & np.isfinite(err)] if err.size else np.zeros(0) for p in POSITIONS]
        data = [d if d.size else np.array([np.nan]) for d in data]
        x = np.arange(len(POSITIONS)) + (k - (len(methods) - 1) / 2) * width
        box = ax.boxplot(data, positions=x, widths=0.9 * width, showfliers=False,
                         patch_artist=True)
        for patch in box["boxes"]:
            patch.set_facecolor(f"C{k}")
        ax.plot([], [], color=f"C{k}", lw=6, label=m)
    ax.set_xticks(np.arange(len(POSITIONS)), list(POSITIONS))
    ax.set_ylabel("gaze error (deg)")
    ax.set_xlabel("band position in the frame")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
