"""Confidence intervals of a comparison: means over runs, and paired differences between methods.

Every method flies the same scenes with the same seeds, so a method's result on (scene, seed) is
paired with ours on the same (scene, seed); the paired differences cancel the spread that scenes
and seeds share, which is most of it. Intervals are Student-t intervals of a mean (scipy), exact
for normal data and close for the handful of runs a sweep has.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Hashable, Iterable

import numpy as np
from scipy import stats

LEVEL = 0.95


@dataclass(frozen=True)
class Interval:
    mean: float
    half_width: float  # nan with fewer than two values
    n: int

    @property
    def low(self) -> float:
        return self.mean - self.half_width

    @property
    def high(self) -> float:
        return self.mean + self.half_width

    def excludes_zero(self) -> bool:
        return math.isfinite(self.half_width) and (self.low > 0 or self.high < 0)

    def format(self, digits: int) -> str:
        if not math.isfinite(self.mean):
            return "n/a"
        if not math.isfinite(self.half_width):
            return f"{self.mean:.{digits}f}"
        return f"{self.mean:.{digits}f} ± {self.half_width:.{digits}f}"


def mean_interval(values: Iterable[float], level: float = LEVEL) -> Interval:
    """Mean and `level` t-interval half-width of the finite values."""
    v = np.array([x for x in values if x is not None and math.isfinite(float(x))], float)
    if len(v) == 0:
        return Interval(math.nan, math.nan, 0)
    if len(v) == 1:
        return Interval(float(v[0]), math.nan, 1)
    sem = float(v.std(ddof=1)) / math.sqrt(len(v))
    return Interval(float(v.mean()), float(stats.t.ppf(0.5 + level / 2, len(v) - 1)) * sem, len(v))


def paired_difference(theirs: dict, ours: dict, level: float = LEVEL,
                      unit: Callable[[Hashable], Hashable] | None = None) -> Interval:
    """Interval of the mean of theirs[k] - ours[k] over the keys (e.g. (scene, seed)) both have.

    With `unit` (key -> its unit, e.g. the scene of a (scene, seed) key) the differences are first
    averaged within each unit and the interval is taken over units: the seeds of one scene share
    that scene's effect on the difference, so pooling them as independent pairs would make the
    interval too narrow whenever methods gain differently on different scenes."""
    keys = sorted(set(theirs) & set(ours))
    diffs = {k: float(theirs[k]) - float(ours[k]) for k in keys}
    if unit is None:
        return mean_interval(diffs.values(), level)
    by_unit: dict = {}
    for k, d in diffs.items():
        if math.isfinite(d):
            by_unit.setdefault(unit(k), []).append(d)
    return mean_interval([float(np.mean(v)) for v in by_unit.values()], level)
