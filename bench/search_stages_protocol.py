"""Where the profile search's evaluations and CPU go over the paper protocol's scenes, stage by stage.

``bench/search_stages.py`` books one scene (the speed bench's Canon 600D, a test camera); this books
every search that ``bench/paper_coverage.py`` makes — the same scenes, seeds and noise levels, its
own arguments passed through — with the same hooks (:func:`search_stages.install`), and sums each
stage over all scenes: the scan grids and their minima's refinement, the deciding stage's ranked
scans and descents, the final fit, the start finders, the stage models, and the coarse-view check
(:mod:`calib.wavelength.quadratic_view`). Counts are exact; times are CPU (``time.process_time``)
with the hooks' own small cost. Tuning may look at ``--split validation`` only.

    python bench/search_stages_protocol.py --data-dir ../shared/data/camera_sensitivities \\
        --split validation --variant "LED only" --seed 0 --noise 0.003,0.03 --mappings

(``--noise`` draws each scene from its level's index in the list: a subset of levels gives other
noise draws than the full protocol's.)
"""

from __future__ import annotations

import re
import time
from collections import defaultdict

import paper_coverage
import search_stages

#: A hook's key: ``costs``/``refine``, the search's stage that called it, the profile's bins.
_KEY = re.compile(r"(costs|refine)\s+(\S+)\s+\d+ px")


def stage_of(key: str) -> str:
    """The hook's key without the profile's bin count (which differs from scene to scene)."""
    matched = _KEY.match(key)
    if matched is None:
        return key.strip()
    return f"{matched[1]} {matched[2].split('/')[0]}"


def main() -> None:
    search_stages.install()
    started = time.process_time()
    paper_coverage.main()
    elapsed = time.process_time() - started
    totals: dict[str, list[float]] = defaultdict(lambda: [0, 0, 0.0])
    for key, (calls, points, seconds) in search_stages.BOOK.items():
        entry = totals[stage_of(key)]
        entry[0] += calls
        entry[1] += points
        entry[2] += seconds
    booked = sum(entry[2] for entry in totals.values())
    print(f"\nwhole run {elapsed:.2f} s CPU; booked to the search's stages {booked:.2f} s")
    for stage, (calls, points, seconds) in sorted(totals.items(), key=lambda kv: -kv[1][2]):
        share = seconds / booked if booked else 0.0
        print(
            f"   {stage:36s} {int(calls):6d} calls {int(points):8d} evals {seconds:8.3f} s"
            f" {share:6.1%}"
        )


if __name__ == "__main__":
    main()
