"""CPU time per search evaluation of the response model, apart from how many evaluations a search makes.

One mapping + estimate of the Canon 600D synthetic scene (``wavelength_speed.py``'s: D65 LED, and
LED + FL2) is run once while every call of :meth:`ResponseModel.costs` (a scan's batch of trial
mappings) and :meth:`ResponseModel.residual_lazy` (one mapping of a descent, with its Jacobian) is
recorded with its arguments (with ``--protocol``, also the camera's ``calib validate`` scene, seed 0, its
"LED only" and "LED+FL" variants as ``wavelength_speed.py --protocol`` runs them: the rig's spot,
blurred profiles, the physical family's scans); the recorded calls are then replayed ``--repeats`` times and the
median CPU time (``time.process_time``, one BLAS thread) of each kind is printed, with the number
of trial mappings they cost. The search's own choices (how many evaluations) do not enter: run it
on two checkouts to compare what one evaluation costs (decision 0106).

With ``--against ROOT`` (a second checkout of the project) the same recorded calls are replayed
alternately with this checkout's response model and with the one under ``ROOT`` (its
``ResponseModel``, ``LampColumns`` and ``NodeLayout`` methods put in place of this checkout's on the
recorded models: the two must share the models' fields), and both medians and their ratio are
printed: on a loaded machine two processes run one after the other differ by 10–15 % on their
own, the alternating replay by ~2 % (decision 0157). Each side makes the descents' reference bands
again before its replay (a band one checkout laid out is read as that checkout reads it; decision
0161).

    python bench/evaluation_cost.py --data-dir ../shared/data/camera_sensitivities [--repeats 7] [--protocol] [--against ../base]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import time
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from wavelength_speed import paper_scene, protocol_estimates

from calib.core.blas import one_blas_thread
from calib.core.observations import LampObservation
from calib.methods import estimate
from calib.wavelength import response_model
from calib.wavelength.response_model import ResponseModel

#: The response model's classes whose methods ``--against`` exchanges.
EXCHANGED = ("ResponseModel", "LampColumns", "NodeLayout")


def recorded(run: Callable[[], object]) -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]]]:
    """The ``costs`` and ``residual_lazy`` calls ``run`` makes, with copies of their arrays."""
    costs_calls: list[tuple[Any, ...]] = []
    residual_calls: list[tuple[Any, ...]] = []
    costs, residual_lazy = ResponseModel.costs, ResponseModel.residual_lazy

    def recording_costs(self: ResponseModel, edges_nm: Any, *, adaptive: bool = True) -> Any:
        costs_calls.append((self, np.array(edges_nm), adaptive))
        return costs(self, edges_nm, adaptive=adaptive)

    def recording_residual(self: ResponseModel, edges_nm: Any, edge_jacobian: Any = None) -> Any:
        jacobian = None if edge_jacobian is None else np.array(edge_jacobian)
        residual_calls.append((self, np.array(edges_nm), jacobian))
        return residual_lazy(self, edges_nm, edge_jacobian)

    ResponseModel.costs = recording_costs  # type: ignore[method-assign]
    ResponseModel.residual_lazy = recording_residual  # type: ignore[method-assign]
    try:
        run()
    finally:
        ResponseModel.costs = costs  # type: ignore[method-assign]
        ResponseModel.residual_lazy = residual_lazy  # type: ignore[method-assign]
    return costs_calls, residual_calls


@one_blas_thread
def replay(
    costs_calls: list[tuple[Any, ...]], residual_calls: list[tuple[Any, ...]]
) -> dict[str, float]:
    """CPU seconds of one replay: the scans' batches, the residuals, their Jacobians."""
    spent = {"costs": 0.0, "residual": 0.0, "jacobian": 0.0}
    for model, edges_nm, adaptive in costs_calls:
        started = time.process_time()
        model.costs(edges_nm, adaptive=adaptive)
        spent["costs"] += time.process_time() - started
    for model, edges_nm, edge_jacobian in residual_calls:
        started = time.process_time()
        _, jacobian, _ = model.residual_lazy(edges_nm, edge_jacobian)
        spent["residual"] += time.process_time() - started
        if jacobian is not None:
            started = time.process_time()
            jacobian()
            spent["jacobian"] += time.process_time() - started
    return spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=None)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--protocol", action="store_true", help="also the calib validate scene")
    parser.add_argument(
        "--against",
        type=Path,
        default=None,
        help="a second checkout's root: replay alternately with its response model too",
    )
    args = parser.parse_args()
    other = None if args.against is None else methods_of(args.against)
    camera, basis, scene = paper_scene(args.data_dir, 0.01)
    led, fluorescent = scene.broadband.observation, scene.fluorescent.observation
    runs: list[tuple[str, Callable[[], object]]] = [
        ("LED only", lambda: estimate([led], basis=basis)),
        ("LED + fluorescent", lambda: estimate([led, fluorescent], basis=basis)),
    ]
    if args.protocol:
        runs += protocol_runs(args.data_dir, camera.name)
    for label, run in runs:
        costs_calls, residual_calls = recorded(run)
        if other is not None:
            compare(label, costs_calls, residual_calls, other, args.repeats)
            continue
        replay(costs_calls, residual_calls)  # warm-up: the models' cached layouts
        spent = [replay(costs_calls, residual_calls) for _ in range(args.repeats)]
        trials = sum(np.atleast_2d(edges).shape[0] for _, edges, _ in costs_calls)
        median = {key: statistics.median(one[key] for one in spent) for key in spent[0]}
        print(
            f"{label:24s} scans {1e3 * median['costs']:6.1f} ms ({len(costs_calls)} batches, "
            f"{trials} trial mappings); residuals {1e3 * median['residual']:5.1f} ms and "
            f"Jacobians {1e3 * median['jacobian']:5.1f} ms ({len(residual_calls)}); "
            f"total {1e3 * sum(median.values()):6.1f} ms",
            flush=True,
        )


def methods_of(root: Path) -> dict[tuple[str, str], Callable[..., Any]]:
    """The methods of :data:`EXCHANGED` in ``root``'s ``calib/wavelength/response_model.py``
    (loaded as a module of its own: its functions read its own module's helpers)."""
    path = root / "calib" / "wavelength" / "response_model.py"
    spec = importlib.util.spec_from_file_location("other_response_model", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"no response model at {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return _methods(module)


def _methods(module: types.ModuleType) -> dict[tuple[str, str], Callable[..., Any]]:
    """The plain functions defined on ``module``'s :data:`EXCHANGED` classes, by (class, name)."""
    found: dict[tuple[str, str], Callable[..., Any]] = {}
    for name in EXCHANGED:
        for key, value in vars(getattr(module, name)).items():
            if isinstance(value, types.FunctionType):
                found[(name, str(key))] = value
    return found


def _install(
    methods: dict[tuple[str, str], Callable[..., Any]], absent: frozenset[tuple[str, str]]
) -> None:
    """Put ``methods`` on their classes and take off those named in ``absent``."""
    for (name, key), value in methods.items():
        setattr(getattr(response_model, name), key, value)
    for name, key in absent:
        if key in vars(getattr(response_model, name)):
            delattr(getattr(response_model, name), key)


def rereference(residual_calls: list[tuple[Any, ...]]) -> None:
    """Each recorded descent model's reference band (:attr:`ResponseModel.referenced`, which a
    descent's first residual reads) made again by the methods now installed: a band recorded by
    one checkout is laid out as that checkout's methods read it."""
    seen: set[int] = set()
    for model, _, _ in residual_calls:
        if model.referenced is None or id(model) in seen:
            continue
        seen.add(id(model))
        edges = model.referenced[0]
        object.__setattr__(model, "referenced", (edges, model.reference(edges).referenced[1]))


def compare(
    label: str,
    costs_calls: list[tuple[Any, ...]],
    residual_calls: list[tuple[Any, ...]],
    other: dict[tuple[str, str], Callable[..., Any]],
    repeats: int,
) -> None:
    """``--against``: the recorded calls replayed ``repeats`` times a side, the sides alternating
    (which goes first alternating too), after a warm-up of each; medians and ratios printed."""
    own = _methods(response_model)
    # A method the other checkout lacks stays this checkout's; one only the other has is taken
    # off again when this checkout's side runs.
    theirs = {**own, **other}
    sides = {"this": own, "other": theirs}
    absent = {"this": frozenset(other) - frozenset(own), "other": frozenset()}
    spent: dict[str, list[dict[str, float]]] = {side: [] for side in sides}
    try:
        for round_ in range(repeats + 1):
            order = list(sides) if round_ % 2 else list(sides)[::-1]
            for side in order:
                _install(sides[side], absent[side])
                rereference(residual_calls)
                one = replay(costs_calls, residual_calls)
                if round_:  # the first round warms up both
                    spent[side].append(one)
    finally:
        _install(own, absent["this"])
        rereference(residual_calls)
    medians = {
        side: {key: statistics.median(one[key] for one in spent[side]) for key in spent[side][0]}
        for side in sides
    }
    parts = [
        f"{key} {1e3 * medians['other'][key]:.1f} → {1e3 * medians['this'][key]:.1f} ms "
        f"({medians['this'][key] / max(medians['other'][key], 1e-12):.3f})"
        for key in ("costs", "residual", "jacobian")
    ]
    total = {side: sum(medians[side].values()) for side in sides}
    print(
        f"{label:24s} other → this checkout: {'; '.join(parts)}; total "
        f"{1e3 * total['other']:.1f} → {1e3 * total['this']:.1f} ms "
        f"({total['this'] / max(total['other'], 1e-12):.3f})",
        flush=True,
    )


def protocol_runs(data_dir: str | None, name: str) -> list[tuple[str, Callable[[], object]]]:
    """The camera's ``calib validate`` scene (test split, seed 0): its "LED only" and "LED+FL"
    variants' estimates, the method and options the protocol gives them."""
    runs: list[tuple[str, Callable[[], object]]] = []
    for label, lamps, keywords, _ in protocol_estimates(data_dir, name, ("LED only", "LED+FL")):

        def run(
            lamps: list[LampObservation] = lamps, keywords: dict[str, Any] = keywords
        ) -> object:
            return estimate(lamps, **keywords)

        runs.append((f"spot scene, {label}", run))
    return runs


if __name__ == "__main__":
    main()
