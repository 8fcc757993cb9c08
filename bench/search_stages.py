"""Where the profile search's evaluations and CPU time go, stage by stage, for the speed bench's scenes.

Wraps :class:`calib.wavelength.profile_search.StageFit`'s ``costs`` (a batch of trial mappings)
and ``refine`` (Levenberg–Marquardt descents) and the start finders, and books each call to the
search's stage that made it (the calling function's name, the profile's bin count): the scan
grids, their minima's refinement, the deciding descents, the deepening scans, the red-end
pull-in, the final fit; plus the line match, the starts and what lies outside the search
(:func:`calib.methods.estimate`'s solve and σ budget). Counts are exact; times are CPU
(``time.process_time``) of one run after a warm-up, with the instrumentation's own small cost.

    python bench/search_stages.py --data-dir ../shared/data/camera_sensitivities [--protocol] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from types import FrameType
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from wavelength_speed import PROTOCOL_VARIANTS, paper_scene, protocol_estimates

from calib import wavelength
from calib.core.observations import LampObservation
from calib.methods import estimate
from calib.wavelength import locate, profile_search

BOOK: dict[str, list[float]] = defaultdict(lambda: [0, 0, 0.0])
_DEPTH = [0]


def _caller(skip: int) -> str:
    frame: FrameType | None = sys._getframe(skip)
    names: list[str] = []
    while frame is not None and len(names) < 6:
        name = frame.f_code.co_name
        if name in (
            "_physical_scan",
            "scan_grids",
            "decide",
            "deepen",
            "search_profiles",
            "_line_match",
        ):
            return name
        names.append(name)
        frame = frame.f_back
    return "/".join(names[:3])


def _wrap_costs(original: Callable[..., Any]) -> Callable[..., Any]:
    def costs(self: Any, x: Any) -> Any:
        x2 = np.atleast_2d(x)
        started = time.process_time()
        out = original(self, x)
        if _DEPTH[0] == 0:
            key = f"costs  {_caller(2):16s} {self.models[0].edges_px.size - 1:5d} px"
            entry = BOOK[key]
            entry[0] += 1
            entry[1] += x2.shape[0]
            entry[2] += time.process_time() - started
        return out

    return costs


def _wrap_refine(original: Callable[..., Any]) -> Callable[..., Any]:
    def refine(self: Any, x: Any, *args: Any, **kwargs: Any) -> Any:
        started = time.process_time()
        _DEPTH[0] += 1
        try:
            out = original(self, x, *args, **kwargs)
        finally:
            _DEPTH[0] -= 1
        key = f"refine {_caller(2):16s} {self.models[0].edges_px.size - 1:5d} px"
        entry = BOOK[key]
        entry[0] += 1
        entry[1] += out.evaluations
        entry[2] += time.process_time() - started
        return out

    return refine


def _wrap_plain(module: Any, name: str, label: str) -> None:
    original = getattr(module, name)

    def wrapped(*args: Any, **kwargs: Any) -> Any:
        started = time.process_time()
        out = original(*args, **kwargs)
        entry = BOOK[label]
        entry[0] += 1
        entry[2] += time.process_time() - started
        return out

    setattr(module, name, wrapped)


def install() -> None:
    fit = profile_search.StageFit
    fit.costs = _wrap_costs(fit.costs)  # type: ignore[method-assign]
    fit.refine = _wrap_refine(fit.refine)  # type: ignore[method-assign]
    _wrap_plain(profile_search, "_line_match", "line match (physical)")
    _wrap_plain(profile_search, "lines_and_peaks", "lines and peaks")
    _wrap_plain(profile_search, "fluorescent_starts", "fluorescent starts")
    _wrap_plain(profile_search, "_correlation_starts", "correlation starts")
    _wrap_plain(profile_search, "_stage", "stage models built")
    # Totals (the rows above are parts of them; the estimate is the rest of the run).
    _wrap_plain(locate, "search_profiles", "= the whole search")
    _wrap_plain(wavelength, "locate_mapping", "= the whole mapping (search, lines, σ)")


def run(label: str, function: Callable[[], Any], repeats: int = 1) -> None:
    """One warm-up, then ``repeats`` booked runs: each row their mean (counts and CPU)."""
    function()  # warm-up
    BOOK.clear()
    started = time.process_time()
    for _ in range(repeats):
        result = function()
    total = (time.process_time() - started) / repeats
    details = getattr(getattr(result, "mapping", None), "details", None) or {}
    print(f"\n{label}: {total:.3f} s CPU, {details.get('evaluations')} search evaluations")
    for key, (calls, points, seconds) in sorted(BOOK.items(), key=lambda kv: -kv[1][2]):
        print(
            f"   {key:42s} {calls / repeats:4.0f} calls {points / repeats:6.0f} evals "
            f"{seconds / repeats:7.3f} s"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--protocol", action="store_true")
    parser.add_argument("--repeats", type=int, default=1, help="booked runs a scene (their mean)")
    args = parser.parse_args()
    install()
    camera, basis, scene = paper_scene(args.data_dir, args.noise)
    led, fluorescent = scene.broadband.observation, scene.fluorescent.observation
    for label, lamps in (("LED only", [led]), ("LED + fluorescent", [led, fluorescent])):

        def bench(lamps: list[LampObservation] = lamps) -> Any:
            return estimate(lamps, basis=basis)

        run(f"bench {label}", bench, args.repeats)
    if not args.protocol:
        return
    for label, chosen, keywords, _ in protocol_estimates(
        args.data_dir, camera.name, PROTOCOL_VARIANTS
    ):

        def spot_estimate(
            chosen: list[LampObservation] = chosen, keywords: dict[str, Any] = keywords
        ) -> Any:
            return estimate(chosen, **keywords)

        run(f"spot {label}", spot_estimate, args.repeats)


if __name__ == "__main__":
    main()
