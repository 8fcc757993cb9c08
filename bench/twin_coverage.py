"""Does ``rig demo``'s ±2σ band hold the twin's true camera? Several cameras, named splits.

Issue 15 asks for ±2σ coverage within 85–98 % on the twin (``rig demo`` with ≥ 3 different cameras).
This captures the shipped ``config.yaml`` on the twin once per camera (only the twin's true
sensitivity changes), estimates each session as ``rig demo`` does (the camera prior without the
twin's own body) and reports, per camera: RE (×10⁻², Makabe et al. 2025 Eq. 16), the share of
(wavelength, channel) cells whose truth lies inside ±2σ, the ratio of the stated σ's RMS to the
actual error's RMS, the fit's reduced χ² against the profile noise alone and as the σ budget judges
it (with :data:`calib.methods.uncertainty.MODEL_FLOOR` under the noise), and the quality verdict;
and for the grating efficiency η (issue 17): the share of grid nodes where the twin's true first-order
η (normalised to its maximum, as the estimate is) lies inside the estimate's ±2σ band, and its σ/err.

Splits (issue 15's protocol): the estimate's prior is the bundled rawtoaces-data basis, so
**validation** cameras are rawtoaces-data bodies (left out one at a time: the only cameras a choice
may be judged on, e.g. ``--floors 0,0.005,0.01,0.02``), and **test** cameras come from elsewhere:
colour-science's Nikon 5100 (NPL) always, and, with ``--data-dir``, bodies of the other measured
collections (``--data-dir`` only finds their curves: the prior stays the bundled basis, with or
without a data directory or ``$SPECTRAL_RIG_DATA``). Every row says its split.

The twin's spectrometer has the in-spec wavelength-scale error and slit deviation a real one has
(:mod:`mocks.bench.deviation`, drawn from the station's seed; ``--spectrometer-error off``: exactly
as stated, the twin before decision 0038); ``--seed-per-camera`` gives every camera's station its own
seed, so the ten twins see ten instrument draws instead of one. The twin camera has the stray light
along the band and the per-frame shutter error a real rig has (:mod:`mocks.bench.flaws`, the
validation protocol's ranges, drawn from the station's seed; ``--stray-light off`` and
``--shutter-error off``: without them, the twin before decision 0087). Scores are those of the curve users
get (``sensitivity.csv`` = ``result.json``: negative lobes of the solve set to zero) and its σ,
against the truth's point samples on the estimate's grid. Two diagnoses follow each row (decision
0111): where the delivered curves and the truth have their maximum and the coverage at the best
common scale (a miss of the max-1 normalisation moves every cell), and RE and coverage against the
truth's least-squares projection onto the grid's piecewise-linear curves (what a curve on that grid
can hold: a camera with detail finer than the grid, e.g. colour's Nikon 5100 with its red peak at
595 nm between two 10 nm nodes, differs from its point samples there).

    python bench/twin_coverage.py [--split validation|test|both] [--floors 0.01]
        [--data-dir ../shared/data/camera_sensitivities] [--keep DIR [--reuse]]
        [--spectrometer-error on|off] [--stray-light on|off]
        [--shutter-error on|off] [--seed-per-camera]
        [--validation-cameras N] [--validation-seeds K]
        [--direct-reading interleaving|fit|interleaving-everywhere] [--spot-phase drawn|twin]

``--validation-cameras N`` adds N rawtoaces-data bodies to the six named validation twins (a fixed
draw, never a test body), ``--validation-seeds K`` captures every validation twin at K station seeds:
more validation evidence for a choice. ``--direct-reading fit`` reads the direct spot's colour as
decision 0114 did (the comparison decision 0123 needed; the product reads it as decision 0119 does);
``--direct-reading interleaving-everywhere`` reads every spot with the Bayer interleaving, the
blurred ones too (the product keeps their plain sums): these twins' slit is tilted 0.8°, so this is
the test of the interleaving's σ under the tilt (decisions 0123, 0134). ``--keep DIR --reuse``
estimates the sessions an earlier run with the same options kept in ``DIR`` instead of capturing
them again: a change to the estimator or its σ judged on the very same frames, in a fraction of the
time (the capture is most of a twin's).

The twin places the direct spot so that the first order of the true curve's longest tabulated
wavelength is centred on the frame, so the spot's sub-pixel phase on the Bayer mosaic follows from
the curve's table: every rawtoaces-data body (380–780 nm) met one phase, where the demo's spot is
judged blurred and its plain sums are kept, and the test bodies tabulated over 400–720 nm another,
where it is judged sharp and the interleaving reads it (decision 0136). Each validation twin's spot
is therefore moved by a sub-pixel shift drawn over one Bayer period (``--spot-phase drawn``, the
default; ``twin``: where the twin places it, the protocol before); test twins stay where the twin
places them. Every row prints the spot's position and how many of the twin's direct extractions the
interleaving read.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.core.metrics import relative_error
from calib.core.spectra import DEFAULT_GRID, WavelengthGrid
from calib.core.spectrometer_tolerance import BANDWIDTH_TOLERANCE, WAVELENGTH_SCALE_NM
from calib.evaluation.synthetic import efficiency_coverage
from calib.methods.uncertainty import MODEL_FLOOR, TOLERANCE_SIGMA, BudgetSettings
from calib.model.bases import default_camera_basis
from calib.model.gratings import PHYSICAL_PARAMETER_NAMES
from mocks.bench.deviation import deviation_from_record
from rig.capture import run_capture
from rig.config import RigConfig, load_config
from rig.demo import related_camera_names
from rig.estimate import estimate_session
from rig.twin import read_twin_truth, write_twin_truth

ROOT = Path(__file__).resolve().parents[1]

#: (camera, collection) — the bundled basis's collection: validation.
VALIDATION = (
    ("Canon EOS 5D Mark II", "rawtoaces-data"),
    ("Sony ILCE-7M3", "rawtoaces-data"),
    ("Fujifilm X-T3", "rawtoaces-data"),
    ("Nikon D850", "rawtoaces-data"),
    ("Panasonic DC-GX9", "rawtoaces-data"),
    ("Canon EOS R6", "rawtoaces-data"),
)
#: Outside the basis's collection: test (reported only). Those of a data directory need it.
TEST = (("Nikon 5100 (NPL)", "colour-science"),)
TEST_WITH_DATA = (
    ("Nikon D3X (camspec)", "jiang-2013-camspec"),
    ("Canon 60D (camspec)", "jiang-2013-camspec"),
    ("Pentax K-5 (camspec)", "jiang-2013-camspec"),
)
#: Bodies never drawn as extra validation twins: the test cameras' bodies here and in
#: ``bench/validate_twin.py``'s test split (a body on both sides would leak the test split).
TEST_BODIES = ("Nikon D5100", "Nikon D3X", "Canon 60D", "Pentax K-5", "Canon EOS 600D", "ARRI D21")
#: The draw of the extra validation bodies (``--validation-cameras``): fixed, so runs compare.
EXTRA_VALIDATION_SEED = 20261127
#: The draw of the validation twins' spot phases (``--spot-phase drawn``): fixed, so runs compare.
SPOT_PHASE_SEED = 20261128
#: The colour filter array's period (sensor pixels): the twin's sensor is a 2×2 Bayer mosaic, so a
#: spot moved by a whole period meets the same sites; its phase within one period is what differs.
CFA_PERIOD_PX = 2.0


def spot_shift(camera: str, seed_offset: int) -> tuple[float, float]:
    """The validation twin's spot shift (x, y sensor pixels), uniform over one Bayer period.

    Where the twin places the spot follows from the true curve's tabulated range (the first order
    of its longest wavelength is centred on the frame), so every rawtoaces-data body (380–780 nm)
    had its spot at one sub-pixel phase and the test bodies of other collections at another
    (decision 0136); on a real rig the phase is anybody's. Drawn from the camera's name and the
    station's seed offset alone, so a twin's phase does not depend on which others run."""
    rng = np.random.default_rng([SPOT_PHASE_SEED, seed_offset, zlib.crc32(camera.encode())])
    dx, dy = rng.uniform(0.0, CFA_PERIOD_PX, size=2)
    return float(dx), float(dy)


def extra_validation_cameras(count: int) -> list[tuple[str, str]]:
    """``count`` more rawtoaces-data bodies (left out of the basis one at a time, as the named six),
    drawn once with :data:`EXTRA_VALIDATION_SEED` from those not named in :data:`VALIDATION` and not
    a test body (:data:`TEST_BODIES`)."""
    from calib.core.datasets import load_collection

    named = {name for name, _ in VALIDATION}
    eligible = sorted(
        base
        for record in load_collection("rawtoaces-data")
        if (base := record.name.split(" (")[0].strip()) not in named and base not in TEST_BODIES
    )
    order = np.random.default_rng(EXTRA_VALIDATION_SEED).permutation(len(eligible))
    return [(eligible[index], "rawtoaces-data") for index in order[:count]]


@dataclass
class Row:
    """One camera, one floor."""

    split: str
    camera: str
    floor: float
    method: str
    re: float
    coverage: float
    sigma_ratio: float
    chi2_noise: float | None
    chi2_judged: float | None
    verdict: str
    cpu_s: float
    components: dict[str, float]
    eta_coverage: float = math.nan
    eta_sigma_ratio: float = math.nan
    #: η's σ components' RMS over η's error RMS (decision 0126), and the η model the estimate fitted.
    eta_components: dict[str, float] = field(default_factory=dict)
    eta_model: str | None = None
    #: The spectrometer-scale check's mean offset over the grid and its σ (nm), ``None``: none.
    scale_check: tuple[float, float] | None = None
    scale_check_notes: list[str] = field(default_factory=list)
    #: The slit factor (true FWHM / stated) and its σ the same check measured, ``None``: not
    #: measured; with the twin's drawn factor beside it (decision 0159).
    slit_check: tuple[float, float] | None = None
    #: Where the delivered curves and the truth have their maximum: (channel, nm) each.
    peaks: tuple[tuple[str, float], tuple[str, float]] | None = None
    #: The least-squares common scale of the delivered curves onto the truth and the ±2σ coverage
    #: at that scale (the max-1 normalisation's part of the misses).
    common_scale: float = math.nan
    coverage_at_common_scale: float = math.nan
    #: RE and ±2σ coverage against the truth's projection onto the estimate's grid (what a curve
    #: on that grid can hold; the truth's point samples are the scores above).
    re_grid_truth: float = math.nan
    coverage_grid_truth: float = math.nan
    #: The direct spot's centre (sensor pixels, x, y), the direct extractions of the twin's capture
    #: and estimate, and how many of them the Bayer interleaving read (decision 0136).
    spot_px: tuple[float, float] | None = None
    direct_spots: int = 0
    interleaved_spots: int = 0
    #: The station seed's offset the twin was captured with (its spectrometer's and flaws' draw).
    seed_offset: int = 0
    #: Where the estimate fitted the twin's own physical family (decision 0151): the fitted
    #: parameter less the twin's, its stated σ (the fit's, jackknife included) and the direct
    #: equations' χ² per degree of freedom. η's error is this one parameter's, so η's statistical
    #: band is honest when ``eta_parameter_error / eta_parameter_sigma`` has RMS ≈ 1 over twins.
    eta_parameter_error: float = math.nan
    eta_parameter_sigma: float = math.nan
    direct_chi2_per_dof: float = math.nan


def twin_config(
    base: RigConfig,
    camera: str,
    collection: str,
    data_dir: Path | None,
    *,
    in_spec_error: bool = True,
    stray_light: bool = True,
    shutter_error: bool = True,
    seed_offset: int = 0,
    spot_shift_px: tuple[float, float] | None = None,
) -> RigConfig:
    """``base`` with the twin camera's true sensitivity set to ``camera``, the spectrometer's
    in-spec errors, the camera's stray light and its shutter error on or off, the
    station's seed moved by ``seed_offset`` and, with ``spot_shift_px``, the direct spot moved by
    that much (x, y sensor pixels) from where the twin places it (:func:`twin_spot_px`)."""
    data = base.model_dump(mode="json")
    data["seed"] += seed_offset
    data["devices"]["spectrometer"]["in_spec_error"] = in_spec_error
    twin = data["devices"]["camera"]
    twin["stray_light"] = stray_light
    twin["shutter_error"] = shutter_error
    twin["sensitivity"] = camera
    twin["sensitivity_collection"] = collection
    if data_dir is not None and collection not in ("colour-science", "rawtoaces-data"):
        twin["data_dir"] = str(data_dir)
    config = RigConfig.model_validate(data)
    if spot_shift_px is None:
        return config
    x, y = twin_spot_px(config)
    twin["optics"]["spot_position_px"] = [x + spot_shift_px[0], y + spot_shift_px[1]]
    return RigConfig.model_validate(data)


def twin_spot_px(config: RigConfig) -> tuple[float, float]:
    """Where the twin of ``config`` places the direct spot's centre (sensor pixels, x, y)."""
    from mocks.bench.optics import TwinOptics
    from mocks.bench.spec import TwinSpec

    spec = TwinSpec.from_config_data(config.model_dump(mode="json"))
    x, y = TwinOptics.build(spec.twin_camera).layout.spot_centre_px
    return float(x), float(y)


def grid_projection(
    wavelength_nm: np.ndarray, values: np.ndarray, grid_nm: np.ndarray, step_nm: float = 0.5
) -> np.ndarray:
    """``values`` ``(n, 3)`` sampled at ``wavelength_nm`` (linear between samples), projected by least
    squares onto the piecewise-linear curves with nodes ``grid_nm`` (the hat functions over the
    grid's span): the node values of the grid curve closest to the truth, ``(len(grid_nm), 3)``.

    A node's value differs from the truth's point sample where the curve bends within a grid step,
    by ``−h² s''/12`` (``h`` the step): a peak between nodes raises the nodes beside it.
    """
    grid = np.asarray(grid_nm, dtype=np.float64)
    fine = np.arange(grid[0], grid[-1] + step_nm / 2, step_nm)
    truth = np.stack(
        [np.interp(fine, wavelength_nm, values[:, k]) for k in range(values.shape[1])], axis=1
    )
    hats = np.stack([np.interp(fine, grid, row) for row in np.eye(grid.size)], axis=1)
    projected, *_ = np.linalg.lstsq(hats, truth, rcond=None)
    return np.asarray(projected, dtype=np.float64)


def normalisation_diagnosis(
    curves: np.ndarray, sigma: np.ndarray, reference: np.ndarray, wavelength_nm: np.ndarray
) -> dict[str, object]:
    """Both max-1 curves ``(f, 3)``: where each has its maximum, the common scale that best maps
    ``curves`` onto ``reference`` and the ±2σ coverage at that scale (``σ`` scaled alike). A scale
    far from 1 with a coverage far above the max-1 one: the misses are the normalisation's (the
    estimate's maximum node off its truth moves every cell)."""

    def peak(values: np.ndarray) -> tuple[str, float]:
        row, channel = np.unravel_index(int(np.argmax(values)), values.shape)
        return "RGB"[channel], float(wavelength_nm[row])

    scale = float(np.sum(curves * reference) / np.sum(curves * curves))
    return {
        "peaks": (peak(curves), peak(reference)),
        "common_scale": scale,
        "coverage_at_common_scale": float(
            np.mean(np.abs(scale * curves - reference) <= 2.0 * scale * sigma)
        ),
    }


def physical_parameter_scores(record: object, grating: object) -> tuple[float, float, float]:
    """The estimate's physical parameter less the twin's, its stated σ, and the direct equations'
    χ²/dof (``diagnostics["grating_model"]`` against the twin's ``grating`` record); NaNs where the
    estimate did not fit the twin's own family."""
    nan = (math.nan, math.nan, math.nan)
    if not isinstance(record, dict) or not isinstance(grating, dict):
        return nan
    kind = grating.get("kind")
    if record.get("model") != kind or kind not in PHYSICAL_PARAMETER_NAMES:
        return nan
    name = PHYSICAL_PARAMETER_NAMES[kind]
    parameters = record.get("parameters") or {}
    if name not in parameters or name not in grating:
        return nan
    equations = int(record.get("direct_equations", 0))
    chi2 = float(record.get("direct_chi2", math.nan))
    return (
        float(parameters[name]) - float(grating[name]),
        float(parameters.get(f"{name}_sigma", math.nan)),
        chi2 / (equations - 2) if equations > 2 else math.nan,
    )


def measured_slit_factor(check: object) -> tuple[float, float] | None:
    """The slit factor and its σ the scale check's record (``diagnostics`` ``check``) holds, the
    bandwidth component's input (:func:`calib.core.spectrometer_scale.measured_slit`); ``None``
    where the check did not measure the slit."""
    if not isinstance(check, dict):
        return None
    factor, sigma = check.get("slit_factor"), check.get("slit_factor_sigma")
    if not isinstance(factor, int | float) or not isinstance(sigma, int | float):
        return None
    return float(factor), float(sigma)


def on_nodes(
    values: np.ndarray, sigma: np.ndarray, wavelength_nm: np.ndarray, nodes_nm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Delivered curves ``(n, 3)`` and their σ on a grid read at ``nodes_nm`` (a subset of its
    nodes: the default grid's), both divided by the curves' maximum there, as a curve delivered on
    those nodes is normalised; on the same nodes, the curves as they are."""
    if np.array_equal(wavelength_nm, nodes_nm):
        return values, sigma
    rows = np.searchsorted(wavelength_nm, nodes_nm)
    if rows.max() >= wavelength_nm.size or not np.allclose(wavelength_nm[rows], nodes_nm):
        raise SystemExit("--grid: its nodes must include every 10 nm node of 400–700 nm")
    peak = float(values[rows].max())
    return values[rows] / peak, sigma[rows] / peak


def judge(
    session: Path,
    out: Path,
    camera: str,
    floor: float,
    *,
    named_only: bool = False,
    tolerance_sigma: float = TOLERANCE_SIGMA,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> dict[str, object]:
    """Estimate ``session`` as ``rig demo`` does, with the σ budget's misfit ``floor`` (the tuning
    run's lever; the product uses :data:`MODEL_FLOOR`) and, with ``named_only``, without the
    validation-fitted factor (the named components alone); score it against the twin's truth."""
    # The bundled rawtoaces-data basis (as on a machine without camera data), whatever --data-dir,
    # $SPECTRAL_RIG_DATA or the user cache hold: the splits are named against it.
    with tempfile.TemporaryDirectory() as no_data:
        basis = default_camera_basis(grid, data_dir=no_data, exclude=related_camera_names(camera))
    assert basis.fallback is not None and "rawtoaces-data" in basis.source, basis.source
    started = time.process_time()
    outcome = estimate_session(
        session,
        out,
        settings={
            "basis": basis,
            "grid": grid,
            "budget": BudgetSettings(
                model_floor=floor,
                coverage_scale={} if named_only else None,
                tolerance_sigma=tolerance_sigma,
            ),
        },
        report=False,
        force=True,
    )
    cpu_s = time.process_time() - started
    result = outcome.estimate.result
    truth = read_twin_truth(session / "twin-truth.json").sensitivity
    # Scored at the default grid's nodes whatever grid the estimate was solved on (``--grid``).
    wavelength = DEFAULT_GRID.wavelength_nm
    reference = np.stack(
        [np.interp(wavelength, truth.wavelength_nm, truth.values[:, k]) for k in range(3)], axis=1
    )
    reference = reference / reference.max()
    # What users get (sensitivity.csv and result.json): negative lobes set to zero, σ alongside.
    curves = result.camera_curves()
    assert curves.sigma is not None, "every grating method states a σ through the budget"
    values, sigma = on_nodes(curves.values, curves.sigma, result.wavelength_nm, wavelength)
    error = values - reference
    budget = result.quality.uncertainty or {}
    eta_coverage, eta_ratio = math.nan, math.nan
    eta_components: dict[str, float] = {}
    if result.grating_efficiency_sigma is not None:
        true_eta = read_twin_truth(session / "twin-truth.json").grating_efficiency.at(
            result.wavelength_nm
        )
        eta_coverage, eta_ratio = efficiency_coverage(result, true_eta)
        eta_error = np.asarray(result.grating_efficiency) - true_eta / float(np.max(true_eta))
        eta_error_rms = max(float(np.sqrt(np.mean(eta_error**2))), 1e-300)
        eta_budget = dict(budget.get("grating_efficiency", {}).get("rms", {}))
        eta_components = {name: float(value) / eta_error_rms for name, value in eta_budget.items()}
    eta_record = result.diagnostics.get("grating_model")
    # The twin's physical sheet as the truth file records it (its ``grating`` entry).
    parameter_error, parameter_sigma, chi2_per_dof = physical_parameter_scores(
        eta_record, json.loads((session / "twin-truth.json").read_text()).get("grating")
    )
    error_rms = float(np.sqrt(np.mean(error**2)))
    on_grid = grid_projection(truth.wavelength_nm, truth.values, wavelength)
    on_grid = on_grid / on_grid.max()
    components = {
        name: float(value) / error_rms for name, value in dict(budget.get("rms", {})).items()
    }
    components["factor"] = float(budget.get("coverage_scale", math.nan))
    # The spectrometer-scale check against the FL lamp's Hg lines (decision 0069), if it decided.
    checked = result.diagnostics.get("spectrometer_scale_check") or {}
    check = checked.get("check") if isinstance(checked, dict) else None
    return {
        "scale_check": (
            (float(check["mean_offset_nm"]), float(check["sigma_nm"]))
            if isinstance(check, dict)
            else None
        ),
        "scale_check_notes": list(checked.get("notes", [])) if isinstance(checked, dict) else [],
        "slit_check": measured_slit_factor(check),
        "components": components,
        "method": result.method,
        "re": relative_error(values, reference),
        "coverage": float(np.mean(np.abs(error) <= 2.0 * sigma)),
        "sigma_ratio": float(np.sqrt(np.mean(sigma**2)) / error_rms),
        "chi2_noise": budget.get("noise_only_reduced_chi2"),
        "chi2_judged": budget.get("reduced_chi2"),
        "verdict": result.quality.verdict,
        "cpu_s": cpu_s,
        "eta_coverage": eta_coverage,
        "eta_sigma_ratio": eta_ratio,
        "eta_components": eta_components,
        "eta_model": eta_record.get("chosen") if isinstance(eta_record, dict) else None,
        "eta_parameter_error": parameter_error,
        "eta_parameter_sigma": parameter_sigma,
        "direct_chi2_per_dof": chi2_per_dof,
        **normalisation_diagnosis(values, sigma, reference, wavelength),
        "re_grid_truth": relative_error(values, on_grid),
        "coverage_grid_truth": float(np.mean(np.abs(values - on_grid) <= 2.0 * sigma)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("validation", "test", "both"), default="both")
    parser.add_argument("--floors", default=str(MODEL_FLOOR), help="comma-separated floors")
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--config", type=Path, default=ROOT / "config.yaml")
    parser.add_argument(
        "--grid",
        type=WavelengthGrid.parse,
        default=DEFAULT_GRID,
        help="solve on this grid (START:STOP:STEP nm; the basis on it too), scored at the default "
        "grid's nodes (400–700 nm every 10 nm, the curves normalised there)",
    )
    parser.add_argument("--keep", type=Path, default=None, help="keep the sessions here")
    parser.add_argument(
        "--reuse",
        action="store_true",
        help="with --keep: estimate a twin's session kept there by an earlier run of the same "
        "options instead of capturing it again (a change to the estimator judged on the same "
        "frames; the twin is deterministic, so a fresh capture gives the same session)",
    )
    parser.add_argument(
        "--spectrometer-error",
        choices=("on", "off"),
        default="on",
        help="the twin spectrometer's in-spec scale and slit errors (off: exactly as stated)",
    )
    parser.add_argument(
        "--stray-light",
        choices=("on", "off"),
        default="on",
        help="the twin camera's stray light along the band (off: none, the twin before 0087)",
    )
    parser.add_argument(
        "--shutter-error",
        choices=("on", "off"),
        default="on",
        help="the twin camera's per-frame shutter error (off: exact, the twin before 0087)",
    )
    parser.add_argument(
        "--tolerance-sigma",
        type=float,
        default=TOLERANCE_SIGMA,
        help="σ of the spectrometer's errors per unit of their tolerance (1/√3 ≈ 0.577: a bound)",
    )
    parser.add_argument(
        "--named-only",
        action="store_true",
        help="the σ budget's named components alone (no validation-fitted factor)",
    )
    parser.add_argument(
        "--seed-per-camera",
        action="store_true",
        help="each camera's station its own seed (config seed + its index): its own spectrometer "
        "draw and noise; default: the config's seed for all",
    )
    parser.add_argument(
        "--validation-cameras",
        type=int,
        default=0,
        help="this many more validation twins: rawtoaces-data bodies beyond the named six, drawn "
        "once with a fixed seed (never a test body)",
    )
    parser.add_argument(
        "--validation-seeds",
        type=int,
        default=1,
        help="each validation twin captured with this many station seeds (config seed + 0, 1, …; "
        "more noise and spectrometer draws)",
    )
    parser.add_argument(
        "--direct-reading",
        choices=("interleaving", "fit", "interleaving-everywhere"),
        default="interleaving",
        help="the direct spot's colour on a Bayer sensor: the cells' interleaving where the spot is "
        "sharp (decision 0119 with its merge addendum, the product), decision 0114's shared-shape "
        "fit with the fit − sum difference in its σ, or the interleaving on every spot, the "
        "blurred ones too (decision 0119 before the addendum; these twins' spots are blurred, so "
        "this is what puts the interleaving and its σ under the slit's tilt to the test) — the "
        "last two comparisons, not the product",
    )
    parser.add_argument(
        "--spot-phase",
        choices=("drawn", "twin"),
        default="drawn",
        help="the validation twins' direct spot: moved by a sub-pixel shift drawn per twin over one "
        "Bayer period (the phases a rig meets), or where the twin places it (one phase for every "
        "rawtoaces-data body: the protocol before decision 0136); test twins are always where "
        "the twin places them",
    )
    parser.add_argument(
        "--camera",
        action="append",
        default=None,
        help="only this camera of the split(s) (repeatable; a quick look, not a table)",
    )
    args = parser.parse_args()
    if args.reuse and args.keep is None:
        parser.error("--reuse reads the sessions --keep kept: give --keep")
    floors = [float(item) for item in args.floors.split(",")]
    if args.direct_reading == "fit":
        from calib.image.profiles import extraction

        extraction._interleaved_direct = lambda *_args, **_kwargs: None
    elif args.direct_reading == "interleaving-everywhere":
        from calib.image.profiles import extraction

        resolved_direct = extraction._resolved_direct

        def everywhere(*resolved_args, **resolved_kwargs):  # type: ignore[no-untyped-def]
            # A blurred spot (no fit, no note) is read like one whose fit failed: the
            # interleaving, else the plain sums.
            values, note, aliasing = resolved_direct(*resolved_args, **resolved_kwargs)
            if values is None and note is None:
                return None, extraction.FIT_FAILED, None
            return values, note, aliasing

        extraction._resolved_direct = everywhere
    spots = _count_direct_readings()
    cameras: list[tuple[str, str, str, int]] = []
    if args.split in ("validation", "both"):
        for seed in range(args.validation_seeds):
            cameras += [
                ("validation", name, coll, seed)
                for name, coll in (*VALIDATION, *extra_validation_cameras(args.validation_cameras))
            ]
    if args.split in ("test", "both"):
        cameras += [("test", name, coll, 0) for name, coll in TEST]
        if args.data_dir is not None:
            cameras += [("test", name, coll, 0) for name, coll in TEST_WITH_DATA]
    if args.camera:
        cameras = [item for item in cameras if item[1] in args.camera]
    base = load_config(args.config)
    rows: list[Row] = []
    with tempfile.TemporaryDirectory() as scratch:
        root = args.keep or Path(scratch)
        for index, (split, camera, collection, seed) in enumerate(cameras):
            config = twin_config(
                base,
                camera,
                collection,
                args.data_dir,
                in_spec_error=args.spectrometer_error == "on",
                stray_light=args.stray_light == "on",
                shutter_error=args.shutter_error == "on",
                seed_offset=(index if args.seed_per_camera else 0) + seed,
                spot_shift_px=(
                    spot_shift(camera, seed)
                    if split == "validation" and args.spot_phase == "drawn"
                    else None
                ),
            )
            spot_px = twin_spot_px(config)
            spots.update(direct=0, interleaved=0)
            slug = "".join(c if c.isalnum() else "_" for c in camera) + f"_{seed}"
            kept = sorted((root / slug / "sessions").glob("*/twin-truth.json"))
            if args.reuse and len(kept) == 1:
                session, truth_file = kept[0].parent, kept[0]
            else:
                captured = run_capture(config, out_dir=root / slug / "sessions")
                if captured.exit_status != "success":
                    print(f"{camera}: capture ended {captured.exit_status}; skipped")
                    continue
                session = captured.session
                truth_file = write_twin_truth(config, session)
            drawn = read_twin_truth(truth_file).spectrometer or {}
            drawn_mean_nm: float | None = None
            if (deviation := deviation_from_record(drawn)) is not None:
                drawn_mean_nm = float(
                    np.mean(
                        deviation.true_wavelength_nm(DEFAULT_GRID.wavelength_nm)
                        - DEFAULT_GRID.wavelength_nm
                    )
                )
                # The draw against the σ the budget states for it (decision 0055: with one shared
                # draw the twins see one realisation of a distribution, not the distribution).
                grid_nm = DEFAULT_GRID.wavelength_nm
                scale_rms = float(
                    np.sqrt(np.mean((deviation.true_wavelength_nm(grid_nm) - grid_nm) ** 2))
                )
                print(
                    f"{camera}: seed {config.seed}, spectrometer scale error "
                    f"{drawn['wavelength_error_at_380_nm']:+.2f} nm at 380, "
                    f"{drawn['wavelength_error_at_780_nm']:+.2f} nm at 780 (RMS over the grid "
                    f"{scale_rms:.2f} nm; the budget's σ {WAVELENGTH_SCALE_NM * TOLERANCE_SIGMA:.2f}"
                    f" nm), slit ×{drawn['bandwidth_factor']:.3f} (σ "
                    f"{100 * BANDWIDTH_TOLERANCE * TOLERANCE_SIGMA:.0f} %)",
                    flush=True,
                )
            for floor in floors:
                scored = judge(
                    session,
                    root / slug / f"estimate-{floor:g}",
                    camera,
                    floor,
                    named_only=args.named_only,
                    tolerance_sigma=args.tolerance_sigma,
                    grid=args.grid,
                )
                rows.append(Row(split, camera + (f" #{seed}" if seed else ""), floor, **scored))  # type: ignore[arg-type]
                row = rows[-1]
                row.spot_px = spot_px
                row.direct_spots, row.interleaved_spots = spots["direct"], spots["interleaved"]
                row.seed_offset = seed
                spots.update(direct=0, interleaved=0)
                print(
                    f"{split:10s} {camera:24s} floor {floor:<6g} {row.method:9s} "
                    f"RE {100 * row.re:5.2f}  ±2σ {100 * row.coverage:5.1f} %  "
                    f"σ/err {row.sigma_ratio:4.2f}  χ² {row.chi2_noise or math.nan:7.3g} → "
                    f"{row.chi2_judged or math.nan:6.3g}  {row.verdict}  "
                    f"η ±2σ {100 * row.eta_coverage:5.1f} %  η σ/err {row.eta_sigma_ratio:4.2f}",
                    flush=True,
                )
                print(
                    f"    direct spot at ({spot_px[0]:.3f}, {spot_px[1]:.3f}) px: the interleaving "
                    f"read {row.interleaved_spots} of {row.direct_spots} extractions",
                    flush=True,
                )
                if row.scale_check is not None:
                    offset, sigma = row.scale_check
                    truth_text = (
                        ""
                        if drawn_mean_nm is None
                        else f"; drawn {drawn_mean_nm:+.3f} nm, error {offset - drawn_mean_nm:+.3f}"
                    )
                    print(
                        f"    scale check: mean offset over the grid {offset:+.3f} ± {sigma:.3f} nm"
                        + truth_text,
                        flush=True,
                    )
                if row.slit_check is not None:
                    # The bandwidth component's one σ, hypot(k − 1, σ_k), against what the
                    # stated slit is really off by (decision 0159).
                    factor, factor_sigma = row.slit_check
                    drawn_text = (
                        f"; drawn ×{drawn['bandwidth_factor']:.3f}, the stated slit off by "
                        f"{100 * abs(drawn['bandwidth_factor'] - 1.0):.1f} %"
                        if "bandwidth_factor" in drawn
                        else ""
                    )
                    print(
                        f"    slit check: ×{factor:.3f} ± {factor_sigma:.3f}, the bandwidth "
                        f"component's one σ {100 * math.hypot(factor - 1.0, factor_sigma):.1f} %"
                        + drawn_text,
                        flush=True,
                    )
                else:
                    print(f"    scale check: none ({'; '.join(row.scale_check_notes)})", flush=True)
                if row.peaks is not None:
                    (got, got_nm), (true, true_nm) = row.peaks
                    print(
                        f"    normalisation: maximum {got} {got_nm:.0f} nm (truth's {true} "
                        f"{true_nm:.0f} nm), common scale {row.common_scale:.4f} → ±2σ "
                        f"{100 * row.coverage_at_common_scale:5.1f} %; against the truth's "
                        f"projection on the grid: RE {100 * row.re_grid_truth:5.2f}, ±2σ "
                        f"{100 * row.coverage_grid_truth:5.1f} %",
                        flush=True,
                    )
                print(
                    "    σ component RMS / error RMS: "
                    + ", ".join(f"{name} {value:.2f}" for name, value in row.components.items()),
                    flush=True,
                )
                if row.eta_components:
                    print(
                        f"    η ({row.eta_model}) σ component RMS / η error RMS: "
                        + ", ".join(
                            f"{name} {value:.2f}" for name, value in row.eta_components.items()
                        ),
                        flush=True,
                    )
                if not math.isnan(row.eta_parameter_error):
                    print(
                        f"    η's parameter: fitted − twin's {row.eta_parameter_error:+.5f}, "
                        f"stated σ {row.eta_parameter_sigma:.5f} (error/σ "
                        f"{row.eta_parameter_error / row.eta_parameter_sigma:+.2f}); direct "
                        f"equations' χ²/dof {row.direct_chi2_per_dof:.3f}",
                        flush=True,
                    )
    print(
        "\n| split | floor | cameras | mean RE ×10⁻² | mean ±2σ coverage | median σ/err | verdicts "
        "| mean η ±2σ coverage | median η σ/err | mean ±2σ at the common scale "
        "| mean RE / ±2σ against the grid projection |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for split in ("validation", "test"):
        for floor in floors:
            chosen = [r for r in rows if r.split == split and r.floor == floor]
            if not chosen:
                continue
            verdicts = ", ".join(sorted({r.verdict for r in chosen}))
            print(
                f"| {split} | {floor:g} | {len(chosen)} | "
                f"{100 * np.mean([r.re for r in chosen]):.2f} | "
                f"{100 * np.mean([r.coverage for r in chosen]):.1f} % | "
                f"{np.median([r.sigma_ratio for r in chosen]):.2f} | {verdicts} | "
                f"{100 * np.mean([r.eta_coverage for r in chosen]):.1f} % | "
                f"{np.median([r.eta_sigma_ratio for r in chosen]):.2f} | "
                f"{100 * np.mean([r.coverage_at_common_scale for r in chosen]):.1f} % | "
                f"{100 * np.mean([r.re_grid_truth for r in chosen]):.2f} / "
                f"{100 * np.mean([r.coverage_grid_truth for r in chosen]):.1f} % |"
            )
    for split in ("validation", "test"):
        chosen = [r for r in rows if r.split == split and not math.isnan(r.eta_coverage)]
        if not chosen:
            continue
        models = sorted({str(r.eta_model) for r in chosen})
        names = list(dict.fromkeys(name for r in chosen for name in r.eta_components))
        medians = [
            f"{name} {np.median([r.eta_components[name] for r in chosen if name in r.eta_components]):.2f}"
            for name in names
        ]
        print(
            f"{split}: η of {len(chosen)} estimates (models: {', '.join(models)}): bands < 95 % "
            f"{sum(r.eta_coverage < 0.95 for r in chosen)}, σ/err < 1 "
            f"{sum(r.eta_sigma_ratio < 1 for r in chosen)}; median component RMS / η error RMS: "
            + ", ".join(medians)
        )
    for split in ("validation", "test"):
        print_parameter_scores(split, [r for r in rows if r.split == split])
    for split in ("validation", "test"):
        chosen = [r for r in rows if r.split == split]
        if chosen:
            print(
                f"{split}: the interleaving read {sum(r.interleaved_spots for r in chosen)} of "
                f"{sum(r.direct_spots for r in chosen)} direct extractions ("
                f"{sum(r.interleaved_spots > 0 for r in chosen)} of {len(chosen)} estimates)"
            )
    print(f"estimate CPU {sum(r.cpu_s for r in rows):.0f} s for {len(rows)} estimates")


def print_parameter_scores(split: str, rows: list[Row]) -> None:
    """η's one parameter against the twins' (decision 0151), per station seed (the twins of one
    seed share its spectrometer and flaws, so their mean error is that draw's): the mean and
    spread of the fitted − true parameter, the stated σ, RMS(error/σ) (1 if calibrated) and the
    direct equations' pooled χ²/dof, whose square root times the median σ is the spread the
    equations' own scatter predicts."""
    fitted = [r for r in rows if not math.isnan(r.eta_parameter_error)]
    for seed in sorted({r.seed_offset for r in fitted}):
        chosen = [r for r in fitted if r.seed_offset == seed]
        error = np.array([r.eta_parameter_error for r in chosen])
        sigma = np.array([r.eta_parameter_sigma for r in chosen])
        chi2 = float(np.mean([r.direct_chi2_per_dof for r in chosen]))
        print(
            f"{split}: η's parameter at seed + {seed} ({len(chosen)} twins): fitted − true mean "
            f"{np.mean(error):+.5f}, SD {np.std(error):.5f}; stated σ median {np.median(sigma):.5f}; "
            f"RMS(error/σ) {np.sqrt(np.mean((error / sigma) ** 2)):.2f}, within 2σ "
            f"{100 * np.mean(np.abs(error) <= 2 * sigma):.0f} %; direct χ²/dof pooled {chi2:.3f} "
            f"(median σ × √ that {np.median(sigma) * math.sqrt(chi2):.5f})"
        )


def _count_direct_readings() -> dict[str, int]:
    """Count the direct spots the extraction reads (``direct``) and those the Bayer interleaving
    read (``interleaved``) from here on, in the dictionary returned (reset it between twins)."""
    from calib.image.profiles import extraction

    counts = {"direct": 0, "interleaved": 0}
    resolved_direct, interleaved_direct = (
        extraction._resolved_direct,
        extraction._interleaved_direct,
    )

    def resolved(*args, **kwargs):  # type: ignore[no-untyped-def]
        counts["direct"] += 1
        return resolved_direct(*args, **kwargs)

    def interleaved(*args, **kwargs):  # type: ignore[no-untyped-def]
        values = interleaved_direct(*args, **kwargs)
        counts["interleaved"] += values is not None
        return values

    extraction._resolved_direct = resolved
    extraction._interleaved_direct = interleaved
    return counts


if __name__ == "__main__":
    main()
