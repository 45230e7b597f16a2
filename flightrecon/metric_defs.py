"""The one definition of every reported image and geometry metric: its key, label, unit, direction
and display precision, and how per-view values are averaged.

Keys are the names in eval.json, metrics.json, eval_over_frames.csv and the mapper's held-out
evaluation; results already on disk use them, so a key is never renamed. Lengths are reported in
centimetres everywhere a user sees them (`cm`), whatever unit a kernel computes in. Tables, plots,
progress bars and command summaries take labels, units and decimals from here, so one metric reads
the same wherever it appears, and a table cannot show a metric nobody gave a unit and a direction.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Iterable

import numpy as np


def _absent(value: float | None) -> bool:
    return value is None or math.isnan(value)


@dataclass(frozen=True)
class Metric:
    key: str
    label: str  # short, as in the paper's tables
    unit: str  # "" for ratios and scores without a unit
    higher_is_better: bool
    decimals: int

    @property
    def heading(self) -> str:
        """Table column or plot axis title: the label with its unit."""
        return f"{self.label} [{self.unit}]" if self.unit else self.label

    def format(self, value: float | None, missing: str = "n/a") -> str:
        """The value at the metric's precision; `missing` where there is none (None or NaN)."""
        return missing if _absent(value) else f"{value:.{self.decimals}f}"

    def describe(self, value: float | None) -> str:
        """`label value unit` ('label n/a' without a value), for a sentence such as a command's summary."""
        unit = "" if _absent(value) else self.unit
        return " ".join(s for s in (self.label, self.format(value), unit) if s)

    def sort_key(self, value: float) -> float:
        """Key under which `sorted` puts the best value first."""
        return -value if self.higher_is_better else value


METRICS: dict[str, Metric] = {m.key: m for m in (
    Metric("psnr", "PSNR", "dB", True, 2),
    Metric("psnr_covered", "PSNR cov.", "dB", True, 2),
    Metric("ssim", "SSIM", "", True, 3),
    Metric("ssim_covered", "SSIM cov.", "", True, 3),
    Metric("lpips", "LPIPS", "", False, 3),
    Metric("depth_l1_cm", "D-L1", "cm", False, 2),
    Metric("depth_l1_cm_covered", "D-L1 cov.", "cm", False, 2),
    Metric("covered_share", "Covered", "", True, 3),
    Metric("normal_err_deg", "Normal error", "deg", False, 1),
    Metric("accuracy_cm", "Acc", "cm", False, 2),
    Metric("completion_cm", "Comp", "cm", False, 2),
    Metric("chamfer_cm", "CD", "cm", False, 2),
    Metric("precision", "Precision", "", True, 3),
    Metric("recall", "Recall", "", True, 3),
    Metric("fscore", "F-score", "", True, 3),
    # over a flight (experiments.report): the mean of PSNR over the frame budget, and PSNR at the
    # mission time the quickest of the compared runs of a scene needed for the whole budget
    Metric("psnr_auc", "PSNR AUC", "dB", True, 2),
    Metric("psnr_equal_time", "PSNR eq. time", "dB", True, 2),
)}

SUMMARY = ("psnr", "ssim", "depth_l1_cm")  # what a command prints when a map is done

PSNR_MAX_DB = 60.0
"""The PSNR of a view with zero error (the render equals the ground truth, both empty included),
and the most any view scores: an uncapped zero-error view is infinitely good and makes the mean
over views infinite. Per-view PSNR, on all pixels and on covered ones, is capped here before views
are averaged, so means keep their meaning (a mean of per-view dB) and results of maps that never
reach the cap are unchanged; 60 dB is past what 8-bit ground truth can tell apart (its rounding
alone is ~59 dB)."""


def select(*keys: str) -> tuple[Metric, ...]:
    """The metrics of `keys`, in order: a KeyError names a key without a definition."""
    return tuple(METRICS[k] for k in keys)


def summary_line(values: dict, keys: Iterable[str] = SUMMARY) -> str:
    """'PSNR 23.61 dB, SSIM 0.819, D-L1 2.20 cm' from a dict of metric values."""
    return ", ".join(METRICS[k].describe(values[k]) for k in keys)


def cm(metres) -> float:
    """A length in metres (a number or a one-element tensor) in the centimetres metrics report."""
    return 100.0 * float(metres)


def mean_defined(values: Iterable[float]) -> float:
    """Mean of the values that are not NaN; NaN when none is (the policy of `mean_metrics`)."""
    v = [x for x in values if not math.isnan(x)]
    return float(np.mean(v)) if v else math.nan


def mean_metrics(rows: list[dict]) -> dict:
    """Mean of every numeric entry of per-view metric rows, with `views`: the number of rows.

    NaN means the metric is undefined on that view (a covered-pixel metric of a view with no
    covered pixel, a normal error without a valid normal), so the view is left out of that mean
    rather than making it NaN: the all-pixel metrics already charge what the map misses there, and
    one empty view would otherwise erase the mean over all the others. Where views were left out,
    `<key>_views` gives how many the mean is over; NaN when none defines it. No per-view value is
    infinite (PSNR stops at PSNR_MAX_DB), so no mean is. Non-numeric entries (a frame's name) are
    not averaged."""
    out: dict = {}
    for k, v in (rows[0].items() if rows else ()):
        if not isinstance(v, numbers.Real) or isinstance(v, bool):
            continue
        vals = [float(r[k]) for r in rows]
        out[k] = mean_defined(vals)
        used = sum(not math.isnan(x) for x in vals)
        if used < len(rows):
            out[f"{k}_views"] = used
    return {**out, "views": len(rows)}
