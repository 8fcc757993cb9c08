"""A made-up cost landscape of a few valleys standing in for a search stage (its costs, sketch,
descent and settling), for the tests of the probes that look for a valley the search's grids
missed."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from calib.wavelength.least_squares import Solution


def solution(x: np.ndarray, cost: float) -> Solution:
    """A fit at ``x`` with ``cost`` over 1 000 rows, 10 evaluations."""
    return Solution(np.asarray(x, float), np.zeros(1000), np.zeros((1000, 3)), cost, 10)


class Landscape:  # a stage's costs, sketch, descent and settling
    """``valleys`` as (centre, cost); a start within 1.5 nm of one falls into it (the first that
    holds it), any other stays where it is, on ``floor``. Every start is recorded, and every
    sketch's ``give_up_above`` (which the landscape does not act on)."""

    def __init__(self, valleys: Sequence[tuple[np.ndarray, float]], floor: float) -> None:
        self.valleys = tuple(valleys)
        self.floor = floor
        self.starts: list[np.ndarray] = []
        self.bars: list[float] = []

    def costs(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        out = np.full(x.shape[0], self.floor)
        for valley, cost in self.valleys:
            out = np.where(np.max(np.abs(x - valley), axis=1) < 0.75, cost, out)
        return np.asarray(out)

    def sketch(self, x: np.ndarray, give_up_above: float = math.inf) -> Solution:
        self.bars.append(give_up_above)
        self.starts.append(np.asarray(x))
        for valley, cost in self.valleys:
            if np.max(np.abs(x - valley)) < 1.5:
                return solution(valley, cost)
        return solution(x, float(self.costs(x)[0]))

    descend = settle = sketch
