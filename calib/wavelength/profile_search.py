"""The pixel→wavelength mapping from whole profiles: physics first, batched scans, honest basins.

Every stage fits the profiles themselves with the lamp times a per-channel response under the
camera prior (:class:`calib.wavelength.response_model.ResponseModel`). Unlike the search before
issue 16 (kept only as the benchmarks' baseline, ``bench/mapping_before.py``):

- the mapping lives in a **family** (:mod:`calib.wavelength.families`): the grating equation through
  a lens when the profile's pixels are measured from the 0th order (``pixel_origin="direct_spot"``)
  or the rig's geometry is known — with the line density, focal length and incidence as a prior,
  an LED-only search has one or two free directions and starts in the right basin — else the
  paper's quadratic;
- **scans are batched**: a whole grid of trial mappings is one vectorised call on a binned profile,
  and every refinement is Levenberg–Marquardt with the exact Jacobian
  (:mod:`calib.wavelength.least_squares`);
- **the scan covers what the mapping may be**: from the 0th order, the wavelengths at the
  profile's ends over the whole range the result may take (coarse to fine, the focal length solved
  for each incidence: :func:`_physical_scan`) besides the end grids around the correlation starts
  (decision 0043);
- **coarse to fine with few starts**: scan (binned, stiff prior) → the grid's local minima refined
  → distinct basins refined on a finer profile with a flexible response (which decides between
  them) → the best one refined with finer response nodes;
- **ambiguity is measured, not hidden**: each basin's cost is a profile likelihood; the stated σ of
  the mapping (:func:`basin_sigma`) mixes the best basin's curvature with the other basins weighted
  by their likelihood ratio (tempered by the fit's reduced χ², so a model misfit does not make one
  basin look certain) and, for broadband lamps alone, the camera prior's pull
  (:func:`prior_misfit_sigma_nm`); when a competing basin's likelihood ratio passes
  :data:`AMBIGUITY_DELTA_CHI2` the result says so, carries every candidate
  (:class:`MappingSearch`) and states a σ whose ±2σ reaches the competitor;
- **either orientation**: for profiles whose origin is arbitrary, both directions (wavelength rising
  or falling with the pixel) are searched; a mapping that folds back is never returned.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from calib.core.arrays import FloatArray
from calib.core.blas import one_blas_thread
from calib.core.errors import EstimationError, InputError
from calib.core.mapping import QuadraticMapping, TiltedGrating, wavelength_rms_from_covariance
from calib.core.observations import LampObservation, profile_sigma
from calib.core.spectra import WavelengthGrid
from calib.core.spectrometer_scale import scale_sigma_nm
from calib.core.spectrometer_tolerance import IN_SPEC_TOLERANCE_SIGMA, WAVELENGTH_SCALE_NM
from calib.model.bases import CameraPrior
from calib.model.resolution import camera_kernel, match_spectrometer
from calib.wavelength.coarse_check import coarse_view
from calib.wavelength.families import GratingFamily, GratingPrior, QuadraticFamily
from calib.wavelength.hidden_valleys import EXTRA_DESCENTS, end_curvatures, valley_half_width_nm
from calib.wavelength.least_squares import (
    CONVERGED_DELTA_CHI2,
    Evaluation,
    Solution,
    levenberg_marquardt,
)
from calib.wavelength.peaks import Peak, fluorescent_starts, lines_and_peaks
from calib.wavelength.response_model import ResponseModel, fine_step_for
from calib.wavelength.rig_prior import default_prior

Family = QuadraticFamily | GratingFamily
ExactMapping = QuadraticMapping | TiltedGrating
Orientation = Literal["auto", "rising", "falling"]

#: Width (nm) of a binned pixel in the scan, the refinement of its minima, the basin-deciding and
#: the final stage (a bin is never narrower than the profile's own pixels).
SCAN_BIN_NM = 5.0
GLOBAL_BIN_NM = 2.5
REFINE_BIN_NM = 1.0
FINAL_BIN_NM = 0.5
#: Node spacing (nm) of the response in the scan.
SCAN_NODES_NM = 10.0
#: Node spacing (nm) of the response in the refining and deciding stages, and in the final one.
COARSE_NODES_NM = 10.0
FINE_NODES_NM = 5.0
#: Flexibility of the response beyond the camera prior (a fraction of the channel's peak,
#: :func:`calib.wavelength.response_model.response_prior`) in every stage but the deciding one.
FLEXIBILITY = 0.05
#: Flexibility of the response in the quadratic family's deciding stage, which chooses between the
#: basins. A broadband lamp's profile has aliases: moving (part of) the spectrum by the spacing of
#: the lamp's structure (D65 is tabulated at 10 nm and interpolated linearly) changes the profile
#: only by what a response on nodes of that spacing absorbs. Under the stiff prior, a camera unlike
#: the training set can fit an alias better (its response there looks more like the mean camera's)
#: and the mapping lands a whole alias spacing off. Letting the response deviate smoothly (σ: this
#: fraction of the channel's peak, so well beyond the channel itself) hands that choice to the
#: lamp's structure; the prior's covariance still sets how rough the response may be.
#: Leave-one-camera-out on the 44 training cameras (``bench/tune_mapping.py``, 1 % noise) finds
#: 0.05 and 2 equally good for cameras like the others.
LOCAL_FLEXIBILITY = 2.0
#: The scan and its refinement treat noise below this fraction of the profile's peak as this large.
GLOBAL_SIGMA_FLOOR = 0.005
# The final fit stops at the statistical bar ``CONVERGED_DELTA_CHI2`` (least_squares). With its
# stop at 1e-7 of the cost alone, the speed bench's final fits spent 11–12 of their 14–17
# evaluations beyond that point, most of them refused steps (decision 0124). The earlier stages'
# descents keep their stops: their end points choose the basins, and on the validation split's
# broadband paper scenes any change of them moved answers.
#: Quadratic family: the scan shifts the wavelengths at both ends of the profile by this half width
#: and step (nm) around each start (the middle follows): the correlation search's linear starts are
#: 2–25 nm off at the ends on the training cameras (a camera unlike the mean, the mapping's
#: curvature). At most this many starts per direction, at least a step apart, are scanned.
QUADRATIC_SCAN = (24.0, 4.0)
MAX_STARTS = 2
#: Quadratic family, a line lamp's lines matched to the profile's peaks: the second match (and
#: its straight companion) is scanned too when it scores at least this share of the first's
#: soft inlier count and lies beyond the first's scan (decision 0188: on the validation split's
#: leave-one-camera-out FL2 paper scenes, 1–3 % noise, four answers 17–33 nm RMS off or failed
#: went to 0.2–1.3 nm, one went 2.2 → 3.0 nm, 299 of 308 unchanged; 0.8 gave the same answers).
SECOND_MATCH_SCORE = 0.9
#: At most this many distinct scan minima are refined (the physical family's scan has up to six
#: grids; on the validation split 8 gave the answers of 24 at 0.9× the CPU).
MAX_REFINED = 8
#: Around each refined scan minimum, the ends are scanned again this finely (half width, step nm).
LOCAL_SCAN = (6.0, 2.0)
#: Quadratic family, broadband lamps alone: at most this many distinct scan minima are refined
#: (decision 0115: the lowest ones hold the answer). Validation split, the leave-one-camera-out
#: paper scenes (``bench/wavelength_loco.py --scenario paper``; D65, seeds 11–13, and LED-B3, seed
#: 11: 176 scenes): every mapping's RMS error as with :data:`MAX_REFINED`, 2 warnings moved (right
#: mappings, one each way). With 3 (and no second descent from the local scan), seed 11's mean
#: RMS rose from 0.60 to 1.00 nm.
BROADBAND_QUADRATIC_REFINED = 4
#: Grating family: the same end grid, for the prior's focal length (±1σ when it is loose) or,
#: without one, for each of these (px).
#: Without a focal length, the scan covers wide-angle to telephoto at typical pitches (the curvature
#: of the first order sets it; one value per ×1.5).
UNKNOWN_FOCAL_LENGTHS_PX = tuple(float(f) for f in np.geomspace(800.0, 40000.0, 10))
#: Local minima of a scan refined (per family), and the distinct basins among them (> 1 nm apart
#: somewhere) carried to the deciding stage.
SCAN_MINIMA = 4
MAX_BASINS = 3
#: Quadratic family with line lamps that cannot place their lines: the best basin's red end is
#: moved by these (nm) — the local scan's half width (:data:`LOCAL_SCAN`) and twice it, either
#: way — and descended from on the deciding profile (decision 0149).
RED_END_PROBE_NM = (-2 * LOCAL_SCAN[0], -LOCAL_SCAN[0], LOCAL_SCAN[0], 2 * LOCAL_SCAN[0])
#: With a line lamp, a scan basin whose refined χ² is this far behind the best one (tempered by
#: the best one's reduced χ²) gets no more descents, only its cost in the deciding stage. On the
#: speed bench's LED + FL2 scenes of 35 training cameras (leave-one-out basis) the 59 basins
#: beyond it (from 1 571) all stayed ≥ 1 566 behind after the deciding fit; the closest calls
#: started far lower (92 → 3.5, 308 → 43). Decision 0065. With a broadband lamp alone, a deciding
#: basin this far behind the best descent gets no scan of the ends about it (decision 0076) and
#: no second descent from its own point (decision 0143).
HOPELESS_DELTA_CHI2 = 1000.0

#: A competing basin whose tempered Δχ² is below this is an ambiguity: warned about, carried in the
#: result. Chosen on validation cameras only — leave-one-camera-out over the 44 training cameras,
#: ``bench/wavelength_loco.py``, 264 scenes (paper/spot/rig geometry × LED-B3/D65): 25 warns on
#: 10 of the 32 scenes whose mapping was > 3 nm off and on 37 of the 232 that were not; 100
#: would warn on 27 failures but on half the good scenes. Decision 0025.
AMBIGUITY_DELTA_CHI2 = 25.0
#: With broadband lamps alone (no line), the same threshold is this. The basins' Δχ² then comes
#: from the camera prior's shape alone, and a camera unlike the prior's collection lets a wrong
#: basin win by more: over 200 physically transformed validation cameras (IR-cut edge, blue
#: edge, CFA dye shifts, colour filters; :mod:`calib.evaluation.validation.transforms`, LED only
#: with and without EXIF) the truth's basin stood 25–47 behind the chosen one, and the right
#: mappings' runner-up had a median of 243. 100 warns on 7 of the 16 wrong mappings (> 3 nm)
#: left unwarned by 25 (the 9 left: CFA dyes shifted 4–8 nm, no basin nearer the truth), and on
#: 8 % (EXIF) and 16 % (no EXIF) of the right mappings of the validation split's 101 cameras
#: (with EXIF, offline: 25: 1 %, 50: 2 %, 200: 21 %). Decision 0094. Re-judged on decision 0098's
#: capture (longer brackets, less noise; decision 0104): over the validation split with 60
#: predicted and 100 transformed cameras (seed 0, 44 + 56 + 100 scenes, LED only with and without
#: EXIF) 100 left 6 / 4 mappings > 3 nm unwarned, all transformed (runner-ups 107–474 behind,
#: 9–17 nm away); 400 leaves 2 / 1 and warns one more right mapping in each (offline: 28 → 29,
#: 27 → 28 of ~185); 1 000 warns 4–5 more right ones.
BROADBAND_AMBIGUITY_DELTA_CHI2 = 400.0
#: A competing basin closer than this (RMS, nm) is the same answer, whatever its Δχ².
AMBIGUITY_MIN_DISTANCE_NM = 1.0
#: The basins' likelihood ratios are tempered by this before weighting the stated σ: the Δχ² of a
#: misspecified camera prior is not χ²-distributed. With :data:`LOCAL_SIGMA_SCALE` chosen on the
#: same 264 LOCO scenes (median actual/stated error 0.83; rig geometry: RMS ratio 1.22). Re-judged
#: on decision 0098's capture for broadband-only mappings (decision 0108: 200 validation scenes, LED
#: only with and without EXIF): 3 to 30 moves the ±2σ coverage by ≤ 0.3 points (the basins behind
#: the best are Δχ² ≫ 30 apart), so it stays.
BASIN_TEMPER = 3.0
#: The local (curvature) σ understates what the prior's pull does to a camera unlike the others:
#: on the LOCO scenes whose basin was right, actual/local RMS error had a median of 1.9. Re-judged
#: by decision 0108 (the same 200 LED-only scenes): 1 → 4 moves the pooled ±2σ from 91.0 to 93.0 %
#: and the median ratio from 0.62 to 0.50, the transformed cameras' from 86.7 to 88.9 % — no value
#: both covers them and stays honest on the others; kept (it serves line-lamp searches, not judged).
LOCAL_SIGMA_SCALE = 2.0
#: The camera prior's pull on a mapping found from broadband lamps alone, per scene
#: (:func:`prior_misfit_sigma_nm`), has two named parts, each in units of the deciding fit's
#: curvature σ (Birge-scaled). First, the fit's excess misfit √(reduced χ² − 1): a smooth shape
#: the camera prior does not describe, coherent over many pixels, so it moves the mapping by more
#: than white noise of its size would (which the Birge-scaled curvature already states); this
#: factor is that coherence. Second, :data:`VIEW_DISAGREEMENT_SCALE`. Decision 0117 chose 6 with
#: the first part alone; decision 0128 lowered it to 2 with the second beside it (validation split
#: only: 44 leave-one-body-out, ~56 predicted and 100 transformed scenes, LED only with and
#: without EXIF, seeds 0 and 1). Replaces a flat 0.15 nm × √χ²ᵣ (decisions 0036, 0085, 0094,
#: 0104), which was as wide on a camera the prior describes as on one it does not.
PRIOR_MISFIT_COHERENCE = 2.0
#: The second part of the prior's pull: how far the coarser profile the basins were found on
#: (:data:`GLOBAL_BIN_NM` bins, a stiffer response) puts the answer behind its own best basin,
#: √Δχ² (:func:`calib.wavelength.coarse_check.coarse_view`, tempered by that view's misfit). Both
#: profiles are views of one likelihood: where the camera prior describes the camera their minima
#: agree to within their noise (Δχ² of order 1); where it does not, the finer view's extra rows
#: pull the answer by a misfit that neither curvature states, and √Δχ² is that displacement in
#: the coarse view's σ — a per-scene measurement of the pull, not a rule. The coarse view's
#: curvature σ is √(2.5 nm / 1 nm) ≈ 1.6 × the deciding fit's from the binning alone and wider
#: with its stiffer response: this factor, 2, was chosen with the coherence on the validation split
#: only (decision 0128: 0, 1, 1.5, …, 3 against coherences 0, 2, 3, …, 6; of the pairs that kept
#: every validation group's ±2σ in 85–98 % and its calibrated median within 2× on both seeds, with
#: and without EXIF, the one whose σ told the scenes apart best — the 10–90 % spread of
#: actual/stated error over the unwarned scenes fell from 5.3–6.7× to 3.5–4.7× per run).
VIEW_DISAGREEMENT_SCALE = 2.0
#: A deciding fit whose reduced χ² (the basins' temper) exceeds this fits the camera prior too badly
#: for its likelihood to pick the basin: the result warns (``mapping_ambiguous``) and its σ reaches
#: the nearest other basin. Chosen on the validation split only (decision 0054).
MISFIT_WARN_TEMPER = 8.0
#: σ (nm) of a measured lamp spectrum's wavelength scale as a whole: compact spectrometers state a
#: wavelength accuracy of ±0.5 nm (a uniform error within it: 0.5/√3). A mapping placed by the
#: spectrum's lines or dips moves with it at every pixel, and no profile fit can see it.
SPECTROMETER_SCALE_SIGMA_NM = WAVELENGTH_SCALE_NM * IN_SPEC_TOLERANCE_SIGMA
#: The share of the lamp spectrum's wavelength offset a mapping found from broadband lamps alone
#: takes up (RMS over the profile): measured by decision 0108 on 153 validation scenes rendered at
#: ±0.5 nm spectrometer offsets (``bench/wavelength_validate.py --scale-transfer 0.5``; median
#: 0.32, 16–84 % 0.19–0.46, RMS over cameras 0.36). The profile's shape against the camera
#: prior's channel edges, which are on the true scale, places the rest; the sensitivity's σ
#: budget re-solves that rest against the fixed mapping
#: (:func:`calib.methods.uncertainty.spectrometer_sigma`).
BROADBAND_SCALE_TRANSFER = 0.36


@dataclass(frozen=True)
class Candidate:
    """One basin of the mapping search: its mapping, cost and weight relative to the best."""

    mapping: ExactMapping
    cost: float
    delta_chi2: float
    weight: float
    distance_nm: float

    def to_dict(self, pixel_range: tuple[float, float]) -> dict[str, Any]:
        probe = np.linspace(pixel_range[0], pixel_range[1], 5)
        return {
            "mapping": self.mapping.to_dict(),
            "cost": self.cost,
            "delta_chi2": self.delta_chi2,
            "relative_likelihood": self.weight,
            "rms_distance_nm": self.distance_nm,
            "wavelength_at_pixels_nm": {
                f"{p:g}": float(w)
                for p, w in zip(probe, self.mapping.wavelength_nm(probe), strict=True)
            },
        }


@dataclass(frozen=True)
class BasinSigma:
    """The stated σ of a search's mapping and what it is made of (nm, RMS over the profile).

    Attributes
    ----------
    stated_nm
        Every part below in quadrature, and at least half the distance to a competing basin
        (its ±2σ reaches it).
    spread_nm
        The basins' RMS distance from the best, weighted by their tempered likelihood ratios.
    local_nm, scale_nm, misfit_nm
        The best basin's (scaled) curvature, the lamp spectrum's wavelength scale and the camera
        prior's pull (:func:`prior_misfit_sigma_nm`).
    competing
        The nearest-in-likelihood basin that makes the mapping ambiguous (tempered Δχ² below the
        threshold, further than :data:`AMBIGUITY_MIN_DISTANCE_NM`), else ``None``.
    """

    stated_nm: float
    spread_nm: float
    local_nm: float
    scale_nm: float
    misfit_nm: float
    competing: Candidate | None


def prior_misfit_sigma_nm(temper: float, local_nm: float, view_delta_chi2: float = 0.0) -> float:
    """σ (nm) of the camera prior's pull on a broadband-only mapping, for a deciding fit of reduced
    χ² ``temper`` whose curvature states ``local_nm`` (RMS over the profile, Birge-scaled) and
    whose answer the coarser view of the profile puts ``view_delta_chi2`` behind its own best
    basin: ``local_nm`` × √(C² (``temper`` − 1) + V² ``view_delta_chi2``), with
    C = :data:`PRIOR_MISFIT_COHERENCE` and V = :data:`VIEW_DISAGREEMENT_SCALE` (negative parts
    count as zero).

    Zero where the camera prior describes the profile down to its noise and both views agree;
    wide where the camera is unlike the basis (the fit's excess misfit), where the two views of
    the profile disagree about the answer (the misfit's pull, measured) and where the profile
    pins the mapping weakly (its curvature). Decisions 0117 and 0128: on the validation split's
    leave-one-body-out, predicted and physically transformed cameras the actual error of a right
    LED-only mapping grows with all three; a flat term was too wide on the first and too narrow
    on the last, and the misfit alone told the scenes apart less well than with the views'
    disagreement beside it.
    """
    excess = max(temper - 1.0, 0.0)
    view = max(view_delta_chi2, 0.0) if math.isfinite(view_delta_chi2) else 0.0
    return local_nm * math.sqrt(
        PRIOR_MISFIT_COHERENCE**2 * excess + VIEW_DISAGREEMENT_SCALE**2 * view
    )


def basin_sigma(
    candidates: Sequence[Candidate],
    *,
    local_nm: float,
    scale_nm: float,
    misfit_nm: float,
    ambiguity_delta_chi2: float = AMBIGUITY_DELTA_CHI2,
) -> BasinSigma:
    """The stated σ from the profile likelihood across the basins (best first in ``candidates``).

    Each basin counts with its weight (:attr:`Candidate.weight`) in the spread; a competing basin
    (see :class:`BasinSigma`) widens σ to half its distance, so the stated band holds both answers
    while the warning says which two they are.
    """
    if not candidates:
        raise EstimationError("no basin to state the mapping's σ from")
    weights = np.array([c.weight for c in candidates])
    distances = np.array([c.distance_nm for c in candidates])
    spread = float(np.sqrt(np.sum(weights * distances**2) / weights.sum()))
    stated = math.sqrt(local_nm**2 + spread**2 + scale_nm**2 + misfit_nm**2)
    competing = [
        c
        for c in candidates[1:]
        if c.delta_chi2 < ambiguity_delta_chi2 and c.distance_nm > AMBIGUITY_MIN_DISTANCE_NM
    ]
    other = min(competing, key=lambda c: c.delta_chi2) if competing else None
    if competing:
        stated = max(stated, 0.5 * max(c.distance_nm for c in competing))
    return BasinSigma(stated, spread, local_nm, scale_nm, misfit_nm, other)


@dataclass(frozen=True)
class MappingSearch:
    """What the search found.

    Attributes
    ----------
    mapping
        The report form: a :class:`calib.core.mapping.QuadraticMapping` over the profile with the
        covariance, ``wavelength_rms_nm`` (local curvature and basin spread combined) and the
        search's details (the grating parameters when the family is physical).
    exact
        The mapping in its family (a :class:`calib.core.mapping.TiltedGrating` for the physical
        one).
    candidates
        Every distinct basin, the answer first, then lowest first (a probe's valley kept behind
        the answer can be lower there: decision 0168).
    ambiguous
        A competing basin is within :data:`AMBIGUITY_DELTA_CHI2`.
    warnings
        Sentences for the user (ambiguity, recommendation of a line lamp).
    """

    mapping: QuadraticMapping
    exact: ExactMapping
    candidates: tuple[Candidate, ...]
    ambiguous: bool
    warnings: tuple[str, ...] = ()
    details: dict[str, Any] = field(default_factory=dict)


# ------------------------------------------------------------------------------- stage fits


@dataclass(frozen=True, eq=False)
class StageFit:
    """Several lamps (one frame, one mapping) under one family at one resolution."""

    models: tuple[ResponseModel, ...]
    family: Family
    pixel_range: tuple[float, float]

    @property
    def edges_px(self) -> FloatArray:
        return self.models[0].edges_px

    def valid(self, x: FloatArray) -> FloatArray:
        """Validity of each mapping ``(K, P)`` (a vector) or of one ``(P,)``."""
        x = np.nan_to_num(np.atleast_2d(x), nan=np.inf)
        finite = np.all(np.isfinite(x), axis=1)
        out = np.zeros(x.shape[0], dtype=bool)
        if np.any(finite):
            if isinstance(self.family, GratingFamily):
                out[finite] = self.family.valid(x[finite], self.pixel_range)
            else:
                out[finite] = self.family.valid(x[finite])
        return out

    def costs(self, x: FloatArray) -> FloatArray:
        """Costs of a batch ``(K, P)`` (invalid points: ``inf``)."""
        x = np.atleast_2d(x)
        valid = self.valid(x)
        out = np.full(x.shape[0], np.inf)
        if not np.any(valid):
            return out
        edges = self.family.wavelengths(self.edges_px, x[valid])
        total = sum(model.costs(edges) for model in self.models)
        if isinstance(self.family, GratingFamily):
            total = total + self.family.prior_cost(x[valid])
        out[valid] = total
        return out

    def function(self, x: FloatArray, with_jacobian: bool) -> Evaluation:
        """Residual rows of every lamp (and the grating prior's) at ``x``, the Jacobian left to a
        call (:data:`calib.wavelength.least_squares.ResidualFunction`), or ``None`` if invalid."""
        if isinstance(self.family, GratingFamily):
            evaluated = self.family.evaluate(
                self.edges_px, x, self.pixel_range, with_jacobian=with_jacobian
            )
            if evaluated is None:
                return None
            edges, edge_jacobian = evaluated
        else:
            # One point: :meth:`valid`'s batch handling (NaN to ∞, masks) cost as much as the
            # family's own check; a finite point is judged by the family alone, as there.
            if not (all(map(math.isfinite, x.tolist())) and self.family.valid(x)[0]):
                return None
            edges = self.family.wavelengths(self.edges_px, x)
            edge_jacobian = self.family.jacobian(self.edges_px, x) if with_jacobian else None
        residuals, thunks = [], []
        for model in self.models:
            residual, thunk, _ = model.residual_lazy(edges, edge_jacobian)
            residuals.append(residual)
            if thunk is not None:
                thunks.append(thunk)
        rows: list[FloatArray] = []
        if isinstance(self.family, GratingFamily):
            prior_residual, row_jacobian = self.family.prior_rows(x)
            residuals.append(prior_residual)
            rows.append(row_jacobian)
        # One lamp and no prior rows (an LED alone, the quadratic family): its rows are the
        # residual and its Jacobian the Jacobian, without a copy (decision 0153).
        alone = len(residuals) == 1
        residual = residuals[0] if alone else np.concatenate(residuals)
        if not with_jacobian:
            return residual, None
        if alone and len(thunks) == 1:
            return residual, thunks[0]

        def jacobian() -> FloatArray:
            return np.vstack([thunk() for thunk in thunks] + rows)

        return residual, jacobian

    def fixed_at(self, x: FloatArray) -> StageFit:
        """The same fit with each model's prior scale and penalty weights held at ``x``'s."""
        edges = self.family.wavelengths(self.edges_px, x)
        return replace(self, models=tuple(model.reference(edges) for model in self.models))

    def sketch(self, x: FloatArray, give_up_above: float = math.inf) -> Solution:
        """The scan refinement's descent from a grid point ``x``: one short round (6
        iterations, tolerance 1e-4), enough to find which basin the point lies in;
        ``give_up_above``: :meth:`refine`'s."""
        return self.refine(
            x, max_iterations=6, tolerance=1e-4, rounds=1, give_up_above=give_up_above
        )

    def descend(self, x: FloatArray, give_up_above: float = math.inf) -> Solution:
        """The deciding stage's descent from ``x`` (one round, 10 iterations, tolerance 1e-5),
        its cost then taken at its own prior scale (what a second round held there would
        report), so descents into different basins compare; ``give_up_above``: :meth:`refine`'s."""
        outcome = self.refine(
            x, max_iterations=10, tolerance=1e-5, rounds=1, give_up_above=give_up_above
        )
        return replace(outcome, cost=float(self.costs(outcome.x[None])[0]))

    def settle(self, x: FloatArray) -> Solution:
        """The final stage's descent from ``x``: one round to a tenth of σ
        (:data:`CONVERGED_DELTA_CHI2`, decision 0124)."""
        return self.refine(
            x, max_iterations=10, tolerance=1e-7, rounds=1, gain_tolerance=CONVERGED_DELTA_CHI2
        )

    def refine(
        self,
        x: FloatArray,
        max_iterations: int,
        tolerance: float = 1e-6,
        rounds: int = 2,
        gain_tolerance: float = 0.0,
        give_up_above: float = math.inf,
    ) -> Solution:
        """Levenberg–Marquardt from ``x``, the prior scale and penalties held at the start, then
        (``rounds=2``) once more held at the solution: its cost is then :meth:`costs`' at its own
        point, so the costs of different basins compare. A refused step is cut to the length the
        cost along it allows (``shorten``, decision 0096). ``gain_tolerance``: the descent also stops
        once the Gauss–Newton step predicts less decrease than that
        (:func:`calib.wavelength.least_squares.levenberg_marquardt`; the final fit's
        :data:`CONVERGED_DELTA_CHI2`). ``give_up_above``: the first round also stops once its
        Gauss–Newton model's minimum is above that cost (a start hopelessly behind a leader:
        :func:`hopeless_bar`, decision 0165)."""
        first = levenberg_marquardt(
            self.fixed_at(x).function,
            x,
            max_iterations=max_iterations,
            tolerance=tolerance,
            shorten=True,
            gain_tolerance=gain_tolerance,
            give_up_above=give_up_above,
        )
        if rounds == 1:
            return first
        again = levenberg_marquardt(
            self.fixed_at(first.x).function,
            first.x,
            max_iterations=max(3, max_iterations // 4),
            tolerance=tolerance,
            shorten=True,
            gain_tolerance=gain_tolerance,
        )
        return replace(again, evaluations=first.evaluations + again.evaluations)


def _stage(
    lamps: Sequence[LampObservation],
    family: Family,
    grid: WavelengthGrid,
    prior: CameraPrior,
    *,
    bin_nm: float,
    nm_per_px: float,
    kernel: FloatArray | None,
    node_step_nm: float,
    flexibility: float,
    sigma_floor: float,
    pixel_range: tuple[float, float],
    cut_ramps: bool = False,
    like: StageFit | None = None,
) -> StageFit:
    """The lamps' models on ``bin_nm`` bins and ``node_step_nm`` nodes; ``like``, a stage built
    with the same lamps, bins, nodes, line spread and ``cut_ramps`` (only the flexibility and σ
    floor may differ): its models' layouts and lamp tables are reused
    (:meth:`ResponseModel.with_prior`, the same numbers as a new build)."""
    if like is not None:
        return StageFit(
            tuple(
                model.with_prior(prior, flexibility=flexibility, sigma_floor=sigma_floor)
                for model in like.models
            ),
            family,
            pixel_range,
        )
    factor = max(1, int(bin_nm / max(nm_per_px, 1e-9)))
    stage_kernel = (
        None if kernel is None else (kernel if factor == 1 else binned_kernel(kernel, factor))
    )
    models = tuple(
        ResponseModel.build(
            bin_pixels(lamp, factor),
            grid,
            node_step_nm=node_step_nm,
            prior=prior,
            flexibility=flexibility,
            kernel=stage_kernel,
            sigma_floor=sigma_floor,
            fine_step_nm=fine_step_for(nm_per_px * factor),
            cut_ramps=cut_ramps,
        )
        for lamp in lamps
    )
    return StageFit(models, family, pixel_range)


def bin_pixels(observation: LampObservation, factor: int) -> LampObservation:
    """Merge runs of ``factor`` pixels (profiles summed, σ in quadrature, centres averaged).

    Exact for the profile model, which integrates over each pixel's wavelength interval: merged
    pixels integrate over the merged interval. A remainder at the end is dropped.
    """
    if factor <= 1:
        return observation
    count = (observation.n_pixels // factor) * factor
    sigma = profile_sigma(observation)[:count]
    return replace(
        observation,
        pixel=observation.pixel[:count].reshape(-1, factor).mean(axis=1),
        profile=observation.profile[:count].reshape(-1, factor, 3).sum(axis=1),
        profile_sigma=np.sqrt((sigma**2).reshape(-1, factor, 3).sum(axis=1)),
    )


def binned_kernel(kernel: FloatArray, factor: int) -> FloatArray | None:
    """The blur kernel in units of binned pixels (sampled at the bin centres, renormalised)."""
    half = kernel.size // 2
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    coarse = np.arange(-(half // factor) - 1, half // factor + 2, dtype=np.float64) * factor
    values = np.interp(coarse, offsets, kernel, left=0.0, right=0.0)
    total = float(values.sum())
    return None if total <= 0 else np.asarray(values / total, dtype=np.float64)


# ------------------------------------------------------------------------------- the search


def _behind(solution: Solution, leader: Solution) -> float:
    """Tempered Δχ² of ``solution`` behind ``leader`` (by the leader's reduced χ²)."""
    return (solution.cost - leader.cost) / leader.temper


def hopeless_bar(leader: Solution) -> float:
    """The cost :data:`HOPELESS_DELTA_CHI2` behind ``leader`` (tempered by its reduced χ², as
    :func:`_behind` tempers): a descent whose own Gauss–Newton model ends above it stops there
    (``give_up_above``, decision 0165)."""
    return leader.cost + HOPELESS_DELTA_CHI2 * leader.temper


def _distinct(
    solutions: Sequence[tuple[Family, Solution]],
    pixel_range: tuple[float, float],
    count: int,
    answer: tuple[Family, Solution] | None = None,
) -> list[tuple[Family, Solution]]:
    """Lowest cost first, keeping those that differ from every kept one by > 1 nm somewhere;
    ``answer`` (one of ``solutions``), when given, first whatever its cost (decision 0168)."""
    probe = np.linspace(pixel_range[0], pixel_range[1], 9)
    chosen: list[tuple[Family, Solution, FloatArray]] = []
    ordered = sorted(solutions, key=lambda item: item[1].cost)
    if answer is not None:
        ordered = [answer, *(item for item in ordered if item is not answer)]
    for family, solution in ordered:
        wavelengths = family.wavelengths(probe, solution.x)
        if all(np.max(np.abs(wavelengths - other)) > 1.0 for _, _, other in chosen):
            chosen.append((family, solution, wavelengths))
        if len(chosen) == count:
            break
    return [(family, solution) for family, solution, _ in chosen]


def _shortlisted_costs(
    points: FloatArray, coarse: StageFit, fine: StageFit, keep: int
) -> tuple[FloatArray, int]:
    """``fine``'s costs of the ``keep`` points ``coarse`` ranks lowest (the rest ``inf``), and the
    evaluations made: coarse to fine, for a scan whose argmin is all that is read."""
    costs = coarse.costs(points)
    count = points.shape[0]
    finite = np.flatnonzero(np.isfinite(costs))
    chosen = finite[np.argsort(costs[finite], kind="stable")[:keep]]
    out = np.full(points.shape[0], np.inf)
    if chosen.size:
        out[chosen] = fine.costs(points[chosen])
        count += chosen.size
    return out, count


def _local_minima(costs: FloatArray, shape: tuple[int, ...]) -> list[int]:
    """Flat indices of the grid's local minima (≤ every neighbour), lowest first."""
    from scipy import ndimage

    grid_costs = costs.reshape(shape)
    finite = np.where(np.isfinite(grid_costs), grid_costs, np.inf)
    lowest = ndimage.minimum_filter(finite, size=3, mode="nearest")
    minima = np.flatnonzero((finite <= lowest) & np.isfinite(finite))
    return sorted(minima.tolist(), key=lambda i: float(costs[i]))


def _quadratic_points(
    start: QuadraticMapping,
    family: QuadraticFamily,
    scan: tuple[float, float] = QUADRATIC_SCAN,
) -> tuple[FloatArray, tuple[int, ...]]:
    """The end-shift grid around ``start`` as parameter vectors ``(K, 3)``."""
    half, step = scan
    shifts = np.arange(-half, half + 0.5 * step, step)
    left, right = np.meshgrid(shifts, shifts, indexing="ij")
    base = family.parameters(start)
    points = base[None, :] + np.stack(
        [left.ravel(), 0.5 * (left + right).ravel(), right.ravel()], axis=1
    )
    return points, (shifts.size, shifts.size)


def _grating_points(
    family: GratingFamily, start: QuadraticMapping, pixel_range: tuple[float, float]
) -> tuple[FloatArray, tuple[int, ...]]:
    """Trial gratings on a grid of the wavelengths at both ends of the profile, for each focal length.

    The same end grid as the quadratic family's (in nm, where the cost's resolution lives): for a
    focal length ``F`` and the 0th order at ``p₀``, two points ``(u, λ)`` fix the groove spacing
    and the incidence in closed form. With ``a = atan((u + u₀)/F) − atan(u₀/F)``,
    ``sin(θ + a) − sin θ = 2 cos(θ + a/2) sin(a/2)``, so the ratio of the two wavelengths gives
    ``tan θ = (c_L − q c_R)/(s_L − q s_R)`` with ``c, s = cos(a/2), sin(a/2)`` and
    ``q = (λ_L/λ_R)·s_R/s_L``; then ``d = λ_R / (sin(θ + a_R) − sin θ)``. Points with no
    physical solution (|θ| ≥ 60°) are left out. The soft prior (line density, focal length,
    incidence) enters the scan's cost, so the grid need not respect it.
    """
    soft = family.prior.soft()
    fixed = family.prior.fixed()
    if "log_focal" in fixed:
        focals = [math.exp(fixed["log_focal"])]
    elif "log_focal" in soft:
        mean, sigma = soft["log_focal"]
        focals = [
            math.exp(mean + k * sigma) for k in ((0.0,) if sigma < 0.03 else (-1.0, 0.0, 1.0))
        ]
    else:
        focals = list(UNKNOWN_FOCAL_LENGTHS_PX)
    p0 = fixed.get("zero_order_px", soft.get("zero_order_px", (0.0, 0.0))[0])
    half, step = QUADRATIC_SCAN
    shifts = np.arange(-half, half + 0.5 * step, step)
    ends_px = np.array(pixel_range)
    left_nm, right_nm = np.meshgrid(
        *(start.wavelength_nm(ends_px)[:, None] + shifts), indexing="ij"
    )
    offset = family.axis_offset_px
    rows = []
    keep = []
    for focal in focals:
        along = family.orientation * (ends_px - p0) + offset
        angle = np.arctan(along / focal) - math.atan(offset / focal)
        half_sin, half_cos = np.sin(angle / 2), np.cos(angle / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = (left_nm / right_nm) * half_sin[1] / half_sin[0]
            theta = np.arctan((half_cos[0] - q * half_cos[1]) / (half_sin[0] - q * half_sin[1]))
            spacing = right_nm / (np.sin(theta + angle[1]) - np.sin(theta))
        ok = (np.abs(theta) < math.radians(60.0)) & (spacing > 0) & np.isfinite(spacing)
        full = {
            "zero_order_px": np.full(theta.shape, p0),
            "log_spacing": np.log(np.where(ok, spacing, 1.0)),
            "log_focal": np.full(theta.shape, math.log(focal)),
            "incidence_deg": np.degrees(theta),
            "axis_offset_px": np.full(theta.shape, offset),
        }
        rows.append(np.stack([full[name].ravel() for name in family.names], axis=1))
        keep.append(ok.ravel())
    points = np.concatenate(rows)
    valid = np.concatenate(keep)
    # Invalid points keep their place in the grid (cost inf) so local minima stay local.
    points[~valid] = points[valid][0] if np.any(valid) else points[~valid]
    return np.where(valid[:, None], points, np.nan), (len(focals), shifts.size, shifts.size)


#: The physical scan of a grating seen from its 0th order (no start needed): the wavelengths at
#: the profile's two ends over the range the result may take — the first pixel from
#: ``PHYSICAL_FIRST_NM[0]`` below the working grid's start up to it, the last from the grid's stop
#: up to ``PHYSICAL_LAST_NM[1]`` beyond it (a band the camera sees: silicon behind an IR filter) —
#: at ``PHYSICAL_STEP_NM``, for each incidence of ``PHYSICAL_INCIDENCE_DEG`` (the focal length
#: follows: with the 0th order pinned, two wavelengths and the incidence fix the grating; the
#: incidence, about the prior's mean, mostly moves the profile's middle). The focal length scanned
#: directly (a factor 1.5 per step) moved the red end by 70–100 nm, and the scan missed the basin
#: of two validation cameras (decision 0043). The scan's ±8° is ~1.6σ of the default prior.
PHYSICAL_FIRST_NM = (100.0, 0.0)
PHYSICAL_LAST_NM = (0.0, 300.0)
PHYSICAL_STEP_NM = 10.0
PHYSICAL_INCIDENCE_DEG = (-8.0, 0.0, 8.0)
#: Around this many of the coarse scan's lowest distinct minima, the ends are scanned again
#: (half width, step nm).
PHYSICAL_FINE = (10.0, 2.5)
PHYSICAL_MINIMA = 4
#: A broadband lamp alone: a fine grid whose lowest point lies on its edge is moved there up to
#: this many times (each move up to PHYSICAL_FINE's half width). Its valley can run between the
#: coarse grid's points: an IR cut-off below the prior's ends the profile's signal sooner, and the
#: coarse point at the right ends but the wrong incidence fits worse than one stretched further
#: (decision 0071). With lines the matched lines pin the mapping: never moved.
PHYSICAL_FOLLOW = 3
#: The focal lengths (in units of the last pixel's distance from the axis) over which the
#: incidence is solved for: far beyond any lens and sheet.
_FOCAL_TABLE = np.geomspace(0.05, 200.0, 160)


def _through_two(
    along_a: FloatArray | float,
    along_b: FloatArray | float,
    nm_a: FloatArray,
    nm_b: FloatArray,
    focal: FloatArray,
    offset: float,
) -> tuple[FloatArray, FloatArray]:
    """The incidence (rad) and groove spacing (nm) of the grating that puts ``nm_a`` and ``nm_b``
    at the distances ``along_a``, ``along_b`` (px, measured from the lens axis, ``u + u₀``) for a
    focal length ``focal`` (all broadcast together; NaN or out of range where none exists): the
    closed form of :func:`_grating_points`."""
    angle_a = np.arctan(along_a / focal) - np.arctan(offset / focal)
    angle_b = np.arctan(along_b / focal) - np.arctan(offset / focal)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (nm_a / nm_b) * np.sin(angle_b / 2) / np.sin(angle_a / 2)
        theta = np.arctan(
            (np.cos(angle_a / 2) - q * np.cos(angle_b / 2))
            / (np.sin(angle_a / 2) - q * np.sin(angle_b / 2))
        )
        spacing = nm_b / (np.sin(theta + angle_b) - np.sin(theta))
    return theta, spacing


def _end_points(
    family: GratingFamily,
    pixel_range: tuple[float, float],
    left_nm: FloatArray,
    right_nm: FloatArray,
    incidences_deg: Sequence[float],
) -> FloatArray:
    """Gratings through ``(left_nm, right_nm)`` at the profile's two ends (arrays of one shape) for
    each incidence: shape ``(*left_nm.shape, len(incidences_deg), P)``, NaN where none exists.

    With the 0th order at ``p₀``, two points fix the groove spacing and the incidence in closed
    form for a focal length ``F`` (:func:`_grating_points`); the incidence rises monotonically with
    ``F``, so for a wanted incidence ``F`` is interpolated (in ``log F``) on a table of focal
    lengths and the closed form then gives the grating exactly through both ends. A held focal
    length (the prior's σ = 0) gives one point per end pair whatever ``incidences_deg``.
    """
    fixed = family.prior.fixed()
    p0 = fixed.get("zero_order_px", 0.0)
    offset = family.offset_guess
    ends_px = np.array(pixel_range)
    along = family.orientation * (ends_px - p0) + offset
    left = np.asarray(left_nm, dtype=np.float64)[None, ...]
    right = np.asarray(right_nm, dtype=np.float64)[None, ...]

    def solve(focal: FloatArray) -> tuple[FloatArray, FloatArray]:
        # focal: broadcastable against left/right with the table (or the incidences) in front.
        return _through_two(along[0], along[1], left, right, focal, offset)

    if "log_focal" in fixed:
        focal = np.full((1, *left.shape[1:]), math.exp(fixed["log_focal"]))
    else:
        extra = (1,) * (left.ndim - 1)
        table = (abs(along[1]) * _FOCAL_TABLE).reshape(-1, *extra)
        theta_table, _ = solve(table)
        log_table = np.log(table) + np.zeros_like(theta_table)
        rows = []
        for incidence in incidences_deg:
            below = theta_table - math.radians(incidence)
            # The physical branch rises through the wanted incidence (arctan's wrap at ±90°
            # falls).
            crossing = (below[:-1] <= 0) & (below[1:] > 0)
            found = np.any(crossing, axis=0)
            k = np.argmax(crossing, axis=0)[None, ...]
            b0 = np.take_along_axis(below, k, axis=0)
            b1 = np.take_along_axis(below, k + 1, axis=0)
            f0 = np.take_along_axis(log_table, k, axis=0)
            f1 = np.take_along_axis(log_table, k + 1, axis=0)
            with np.errstate(divide="ignore", invalid="ignore"):
                log_focal = f0 + (f1 - f0) * (-b0) / (b1 - b0)
            rows.append(np.where(found[None, ...], np.exp(log_focal), np.nan))
        focal = np.concatenate(rows, axis=0)
    theta, spacing = solve(focal)
    ok = (
        np.isfinite(theta)
        & np.isfinite(spacing)
        & (spacing > 0)
        & (np.abs(theta) < math.radians(60.0))
    )
    full = {
        "zero_order_px": np.full(theta.shape, p0),
        "log_spacing": np.log(np.where(ok, spacing, 1.0)),
        "log_focal": np.log(np.where(ok, focal, 1.0)),
        "incidence_deg": np.degrees(theta),
        "axis_offset_px": np.full(theta.shape, offset),
    }
    # (incidence, *ends) → (*ends, incidence, P)
    stacked = np.stack([full[name] for name in family.names], axis=-1)
    stacked = np.moveaxis(stacked, 0, -2)
    return np.where(np.moveaxis(ok, 0, -1)[..., None], stacked, np.nan)


def _start_points(
    family: GratingFamily, start: QuadraticMapping, pixel_range: tuple[float, float]
) -> tuple[FloatArray, tuple[int, ...]]:
    """The end grid around a start (:data:`QUADRATIC_SCAN`) for each incidence of
    :data:`PHYSICAL_INCIDENCE_DEG` about the prior's."""
    half, step = QUADRATIC_SCAN
    shifts = np.arange(-half, half + 0.5 * step, step)
    ends = start.wavelength_nm(np.array(pixel_range))
    left, right = np.meshgrid(ends[0] + shifts, ends[1] + shifts, indexing="ij")
    mean = family.prior.values.get("incidence_deg", (0.0, 0.0))[0]
    points = _end_points(
        family, pixel_range, left, right, [mean + k for k in PHYSICAL_INCIDENCE_DEG]
    )
    return points.reshape(-1, points.shape[-1]), points.shape[:-1]


#: A line lamp seen from its 0th order: the strongest lines and profile peaks the physical match
#: pairs (:func:`_line_match`), the soft-inlier width τ (nm) of its score and the tolerance (nm)
#: within which a peak counts as a line's (:func:`calib.wavelength.peaks.match_peak_hypotheses`'
#: values), the prior's bound on each matched geometry (σ multiples: a geometry beyond 3σ of the
#: rig's focal length, incidence or line density is one in 370), and the σ (nm) of a line's
#: position in the matched lines' fit (a centroid on 5 nm bins of a line blurred by the slit).
LINE_MATCH_LINES = 6
LINE_MATCH_PEAKS = 10
LINE_MATCH_TAU_NM = 2.0
LINE_MATCH_TOLERANCE_NM = 1.5
LINE_MATCH_PRIOR_SIGMAS = 3.0
LINE_MATCH_SIGMA_NM = 0.5
#: Distinct line matches (> this far apart somewhere over the profile, nm) kept as starts.
LINE_MATCH_DISTINCT_NM = 3.0
LINE_MATCH_HYPOTHESES = 4


@dataclass(frozen=True)
class LineMatch:
    """A line lamp's lines matched to its profile's peaks through the grating equation.

    Attributes
    ----------
    points
        The matched gratings ``(k, P)``, distinct, best first (each fitted to its matched lines
        under the prior).
    matched
        How many lines each one puts within :data:`LINE_MATCH_TOLERANCE_NM` of a peak.
    scores
        Their soft inlier scores (line strengths, :data:`LINE_MATCH_TAU_NM`).
    unambiguous
        Whether the best one stands alone (see :func:`_line_match`).
    """

    points: FloatArray
    matched: tuple[int, ...]
    scores: tuple[float, ...]
    unambiguous: bool


def _line_match(
    family: GratingFamily,
    lines: Sequence[Peak],
    peaks: Sequence[Peak],
    pixel_range: tuple[float, float],
) -> LineMatch | None:
    """The lamp's lines matched to the profile's peaks through the grating equation with the 0th
    order pinned (``None`` when it is not, or nothing matches).

    With the 0th order at ``p₀`` and a focal length ``F``, two lines at two peaks fix the groove
    spacing and the incidence in closed form (:func:`_through_two`). Every pair of the strongest
    lines at every pair of peaks (the longer wavelength the farther from the 0th order) is solved
    for a table of focal lengths (:data:`_FOCAL_TABLE`); a geometry beyond the prior
    (:data:`LINE_MATCH_PRIOR_SIGMAS`) is dropped and the rest are scored by where they put the
    other peaks (the soft inlier count of :func:`calib.wavelength.peaks.match_peak_hypotheses`).
    Unlike a quadratic through the lines (decision 0076, refusal 1), the extrapolation to the
    profile's ends follows the physics: the 0th order anchors it. The best-scored distinct
    geometries are fitted to their matched lines under the prior.

    The best one is *unambiguous* when it matches at least three lines and no distinct geometry
    matches as many.
    """
    fixed = family.prior.fixed()
    if "zero_order_px" not in fixed or len(lines) < 2 or len(peaks) < 2:
        return None
    strongest = sorted(lines, key=lambda line: -line.prominence)[:LINE_MATCH_LINES]
    line_nm = np.array([line.position for line in strongest])
    weight = np.array([line.prominence for line in strongest])
    weight = weight / weight.max()
    peak_px = np.array(
        [peak.position for peak in sorted(peaks, key=lambda p: -p.prominence)][:LINE_MATCH_PEAKS]
    )
    offset = family.offset_guess
    distance = family.orientation * (peak_px - fixed["zero_order_px"])
    peak_px, distance = peak_px[distance > 0], distance[distance > 0]
    if peak_px.size < 2:
        return None
    along = distance + offset
    ends_along = family.orientation * (np.array(pixel_range) - fixed["zero_order_px"]) + offset
    line_pairs = [
        (i, j) for i in range(line_nm.size) for j in range(line_nm.size) if line_nm[i] < line_nm[j]
    ]
    peak_pairs = [
        (a, b) for a in range(along.size) for b in range(along.size) if distance[a] < distance[b]
    ]
    if not line_pairs or not peak_pairs:
        return None
    li, lj = np.array(line_pairs).T
    pa, pb = np.array(peak_pairs).T
    if "log_focal" in fixed:
        focal = np.array([math.exp(fixed["log_focal"])])
    else:
        focal = abs(float(ends_along[1])) * _FOCAL_TABLE
    # Shapes: (line pairs, peak pairs, focal lengths).
    focal3 = focal[None, None, :]
    theta, spacing = _through_two(
        along[pa][None, :, None],
        along[pb][None, :, None],
        line_nm[li][:, None, None],
        line_nm[lj][:, None, None],
        focal3,
        offset,
    )
    theta, spacing = np.broadcast_arrays(theta, spacing)
    theta, spacing = theta.ravel(), spacing.ravel()
    focal_all = np.broadcast_to(focal3, (len(line_pairs), len(peak_pairs), focal.size)).ravel()
    ok = (
        np.isfinite(theta)
        & np.isfinite(spacing)
        & (spacing > 0)
        & (np.abs(theta) < math.radians(60.0))
    )
    values = {
        "log_spacing": np.log(np.where(ok, spacing, 1.0)),
        "log_focal": np.log(focal_all),
        "incidence_deg": np.degrees(theta),
    }
    for name, (mean, sigma) in family.prior.soft().items():
        if name in values:
            ok &= np.abs(values[name] - mean) <= LINE_MATCH_PRIOR_SIGMAS * sigma
    if not np.any(ok):
        return None
    theta, spacing, focal_all = theta[ok], spacing[ok], focal_all[ok]
    at_axis = np.arctan(offset / focal_all)
    # The peaks' and the profile ends' wavelengths under each geometry.
    turned = theta[:, None] + np.arctan(along[None, :] / focal_all[:, None]) - at_axis[:, None]
    ends = theta[:, None] + np.arctan(ends_along[None, :] / focal_all[:, None]) - at_axis[:, None]
    inside = np.all(np.abs(ends) < 0.5 * math.pi, axis=1) & np.all(
        spacing[:, None] * (np.sin(ends) - np.sin(theta)[:, None]) > 0, axis=1
    )
    predicted = spacing[:, None] * (np.sin(turned) - np.sin(theta)[:, None])
    miss = np.min(np.abs(predicted[:, None, :] - line_nm[None, :, None]), axis=2)
    score = np.where(
        inside, np.sum(weight * np.exp(-0.5 * (miss / LINE_MATCH_TAU_NM) ** 2), axis=1), -np.inf
    )
    order = np.argsort(-score, kind="stable")
    names = family.names
    probe = np.linspace(pixel_range[0], pixel_range[1], 9)

    def vector(k: int) -> FloatArray:
        full = {
            "zero_order_px": fixed["zero_order_px"],
            "log_spacing": math.log(spacing[k]),
            "log_focal": math.log(focal_all[k]),
            "incidence_deg": math.degrees(theta[k]),
            "axis_offset_px": offset,
        }
        return np.array([full[name] for name in names])

    def pairs(x: FloatArray, tolerance: float) -> list[tuple[int, int]]:
        wavelengths = family.wavelengths(peak_px, x)
        chosen: list[tuple[int, int]] = []
        for i in range(line_nm.size):
            gap = np.abs(wavelengths - line_nm[i])
            j = int(np.argmin(gap))
            if gap[j] <= tolerance and all(j != other for _, other in chosen):
                chosen.append((i, j))
        return chosen

    def fit(x: FloatArray) -> FloatArray:
        for tolerance in (2.0 * LINE_MATCH_TOLERANCE_NM, LINE_MATCH_TOLERANCE_NM):
            matched = pairs(x, tolerance)
            if len(matched) < 2:
                return x
            at = peak_px[[j for _, j in matched]]
            target = line_nm[[i for i, _ in matched]]

            def residual(
                y: FloatArray,
                with_jacobian: bool,
                at: FloatArray = at,
                target: FloatArray = target,
            ) -> Evaluation:
                evaluated = family.evaluate(at, y, pixel_range, with_jacobian=with_jacobian)
                if evaluated is None:
                    return None
                wavelengths, jacobian = evaluated
                prior_residual, prior_jacobian = family.prior_rows(y)
                rows = np.concatenate(
                    [(wavelengths - target) / LINE_MATCH_SIGMA_NM, prior_residual]
                )
                if not with_jacobian:
                    return rows, None
                assert jacobian is not None
                return rows, np.vstack([jacobian / LINE_MATCH_SIGMA_NM, prior_jacobian])

            x = levenberg_marquardt(residual, x, max_iterations=20, tolerance=1e-8).x
        return x

    def soft_score(x: FloatArray) -> float:
        gap = np.abs(family.wavelengths(peak_px, x)[None, :] - line_nm[:, None])
        return float(np.sum(weight * np.exp(-0.5 * (np.min(gap, axis=1) / LINE_MATCH_TAU_NM) ** 2)))

    # The best-scored distinct geometries (before their fit), then each fitted and scored again.
    drawn: list[FloatArray] = []
    drawn_wavelengths: list[FloatArray] = []
    for k in order:
        if not np.isfinite(score[k]):
            break
        x = vector(int(k))
        wavelengths = family.wavelengths(probe, x)
        if any(
            np.max(np.abs(wavelengths - w)) <= LINE_MATCH_DISTINCT_NM for w in drawn_wavelengths
        ):
            continue
        drawn.append(x)
        drawn_wavelengths.append(wavelengths)
        if len(drawn) == 2 * LINE_MATCH_HYPOTHESES:
            break
    fitted = sorted(((soft_score(x), x) for x in map(fit, drawn)), key=lambda item: -item[0])
    kept: list[tuple[float, FloatArray, FloatArray]] = []
    for value, x in fitted:
        wavelengths = family.wavelengths(probe, x)
        if any(np.max(np.abs(wavelengths - w)) <= LINE_MATCH_DISTINCT_NM for _, _, w in kept):
            continue
        kept.append((value, x, wavelengths))
        if len(kept) == LINE_MATCH_HYPOTHESES:
            break
    if not kept:
        return None
    matched = tuple(len(pairs(x, LINE_MATCH_TOLERANCE_NM)) for _, x, _ in kept)
    unambiguous = matched[0] >= 3 and all(m < matched[0] for m in matched[1:])
    return LineMatch(
        np.array([x for _, x, _ in kept]), matched, tuple(v for v, _, _ in kept), unambiguous
    )


def _line_start_grids(
    family: GratingFamily,
    starts: Sequence[QuadraticMapping],
    lead: LampObservation,
    prior: CameraPrior,
    grid: WavelengthGrid,
    pixel_range: tuple[float, float],
) -> tuple[list[tuple[FloatArray, tuple[int, ...], FloatArray | None]], bool]:
    """The scan's grids about the starts of a profile seen from its 0th order, and whether they
    come from a line match (then the physical scan over every end is not needed).

    A line lamp's lines matched through the grating equation (:func:`_line_match`), when the
    match is unambiguous, give its distinct geometries; the scan covers the ends about each
    (:func:`_local_end_points`, 147 trial mappings). Otherwise (a broadband lead, a match that
    fails or is ambiguous) the end grids about the starts, at most :data:`MAX_STARTS` of them
    (:func:`_start_points`, 507 each), which the physical scan joins (decision 0076, refusal 2:
    either alone misses some cameras' basins).
    """
    if lead.kind == "fluorescent":
        try:
            lines, peaks, _ = lines_and_peaks(lead, prior.mean, grid)
        except EstimationError:
            lines, peaks = [], []
        match = _line_match(family, lines, peaks, pixel_range)
        if match is not None and match.unambiguous:
            local = [_local_end_points(family, point, pixel_range) for point in match.points]
            side = round(2 * DECIDING_LOCAL_SCAN[0] / DECIDING_LOCAL_SCAN[1]) + 1
            return [(p, (side, side, p.shape[0] // side**2), None) for p in local], True
    grids: list[tuple[FloatArray, tuple[int, ...], FloatArray | None]] = [
        (*_start_points(family, c, pixel_range), None) for c in _spread_starts(starts, pixel_range)
    ]
    return grids, False


def _physical_scan(
    scan: StageFit,
    family: GratingFamily,
    pixel_range: tuple[float, float],
    grid: WavelengthGrid,
    follow: int = 0,
) -> tuple[list[tuple[FloatArray, tuple[int, ...], FloatArray | None]], int]:
    """Coarse to fine over the ends the result may take (:data:`PHYSICAL_FIRST_NM` …): the
    coarse grid's lowest distinct minima, each with a fine grid around it (returned with the
    evaluation count of the grids scanned here). With ``follow``, a fine grid whose lowest point
    lies on its edge is moved there, up to that many times (:data:`PHYSICAL_FOLLOW`). Each fine
    grid comes with its costs when they were computed here (``None``: the caller scans it), so
    no grid is costed twice."""
    step = PHYSICAL_STEP_NM
    first = np.arange(
        grid.start_nm - PHYSICAL_FIRST_NM[0],
        grid.start_nm + PHYSICAL_FIRST_NM[1] + 0.5 * step,
        step,
    )
    last = np.arange(
        grid.stop_nm - PHYSICAL_LAST_NM[0], grid.stop_nm + PHYSICAL_LAST_NM[1] + 0.5 * step, step
    )
    if family.orientation < 0:
        first, last = last, first
    left, right = np.meshgrid(first, last, indexing="ij")
    mean = family.prior.values.get("incidence_deg", (0.0, 0.0))[0]
    coarse = _end_points(
        family, pixel_range, left, right, [mean + k for k in PHYSICAL_INCIDENCE_DEG]
    )
    shape = coarse.shape[:-1]
    points = coarse.reshape(-1, coarse.shape[-1])
    costs = scan.costs(points)
    half, fine_step = PHYSICAL_FINE
    shifts = np.arange(-half, half + 0.5 * fine_step, fine_step)
    grids: list[tuple[FloatArray, tuple[int, ...], FloatArray | None]] = []
    taken: list[tuple[float, float]] = []
    count = points.shape[0]
    for index in _local_minima(costs, shape):
        i, j = np.unravel_index(index, shape)[:2]
        centre = (float(left[i, j]), float(right[i, j]))
        if any(abs(centre[0] - a) <= step and abs(centre[1] - b) <= step for a, b in taken):
            continue
        taken.append(centre)
        fine_costs: FloatArray | None = None
        for moves in range(follow + 1):
            fine_left, fine_right = np.meshgrid(
                centre[0] + shifts, centre[1] + shifts, indexing="ij"
            )
            fine = _end_points(
                family,
                pixel_range,
                fine_left,
                fine_right,
                [mean + k for k in PHYSICAL_INCIDENCE_DEG],
            )
            fine_costs = None
            if moves == follow:
                break
            # A fine grid whose lowest point is on its edge holds no minimum: the valley goes on
            # beyond it (between the coarse grid's points, at an incidence between its own).
            fine_costs = scan.costs(fine.reshape(-1, fine.shape[-1]))
            count += fine_costs.size
            if not np.any(np.isfinite(fine_costs)):
                break
            a, b = np.unravel_index(int(np.argmin(fine_costs)), fine.shape[:-1])[:2]
            if 0 < a < shifts.size - 1 and 0 < b < shifts.size - 1:
                break
            centre = (float(fine_left[a, b]), float(fine_right[a, b]))
        grids.append((fine.reshape(-1, fine.shape[-1]), fine.shape[:-1], fine_costs))
        if len(grids) == PHYSICAL_MINIMA:
            break
    return grids, count


#: Around a deciding basin (grating family, broadband lamps alone): the profile's ends shifted by
#: up to (half width, step) nm, at these incidence offsets (°) about the basin's.
DECIDING_LOCAL_SCAN = (6.0, 2.0)
DECIDING_LOCAL_INCIDENCE_DEG = (-4.0, 0.0, 4.0)
#: The deepening scan (:data:`DECIDING_LOCAL_SCAN`'s 147 gratings) is costed on the scan
#: refinement's profile (:data:`GLOBAL_BIN_NM`) first and only this many of its lowest on the
#: deciding one, whose lowest point is all the scan gives.
DEEPEN_SHORTLIST = 12
#: The quadratic family's deciding scan (:data:`LOCAL_SCAN`'s 49 mappings about a basin) is ranked
#: on the scan refinement's profile (:data:`GLOBAL_BIN_NM`, the deciding flexibility) and only this
#: many of its lowest are costed on the deciding one (decision 0115). Validation split, the
#: leave-one-camera-out paper scenes (D65 with FL2, seeds 11–13, 129 scenes): every answer, σ and
#: warning as with the whole scan costed finely; D65 alone, seed 11, the same summary as without
#: the shortlist; 4 instead of 8 moved the seed-12 D65 mean by 0.002 nm.
DECIDING_SHORTLIST = 8


def _local_end_points(
    family: GratingFamily, x: FloatArray, pixel_range: tuple[float, float]
) -> FloatArray:
    """Gratings whose profile ends lie on a grid (:data:`DECIDING_LOCAL_SCAN`) around ``x``'s,
    at incidences about its own: ``(K, P)``, NaN rows where none exists."""
    half, step = DECIDING_LOCAL_SCAN
    shifts = np.arange(-half, half + 0.5 * step, step)
    ends = family.wavelengths(np.array(pixel_range), x)
    left, right = np.meshgrid(ends[0] + shifts, ends[1] + shifts, indexing="ij")
    incidence = float(x[family.names.index("incidence_deg")])
    points = _end_points(
        family, pixel_range, left, right, [incidence + k for k in DECIDING_LOCAL_INCIDENCE_DEG]
    )
    return points.reshape(-1, points.shape[-1])


def _stretched(
    family: GratingFamily, x: FloatArray, lamp: LampObservation, prior: CameraPrior
) -> bool:
    """Whether ``x`` puts ``lamp``'s red edge beyond the prior mean's by more than
    :data:`RED_EDGE_MARGIN_NM` (decision 0049's stretched red end, which a camera unlike the
    prior's mean can fit better): the deciding stage's second descent looks for the near minimum
    the first one missed, never moves a basin into that end."""
    edge = red_edge_nm(lamp, family.mapping(x), prior)
    return edge is not None and edge[0] - edge[1] > RED_EDGE_MARGIN_NM


def _rig_known(family: GratingFamily) -> bool:
    """Whether the prior gives the groove spacing, focal length and incidence."""
    return all(
        name in family.prior.values for name in ("log_spacing", "log_focal", "incidence_deg")
    )


#: Grid over a rig's prior, in units of each parameter's σ: (σ multiples) per parameter.
PRIOR_GRID: dict[str, tuple[float, ...]] = {
    "log_spacing": (-1.5, 0.0, 1.5),
    "log_focal": (-2.0, -1.0, 0.0, 1.0, 2.0),
    "incidence_deg": tuple(float(k) for k in np.arange(-2.4, 2.41, 0.4)),
}


def _prior_points(family: GratingFamily) -> tuple[FloatArray, tuple[int, ...]]:
    """A grid over the rig's prior (:data:`PRIOR_GRID`; held parameters stay at their value)."""
    soft = family.prior.soft()
    axes = []
    for name in family.names:
        mean, sigma = soft[name]
        axes.append(mean + sigma * np.array(PRIOR_GRID.get(name, (0.0,))))
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1), mesh[0].shape


def _spans_grid(
    mapping: ExactMapping, pixel_range: tuple[float, float], grid: WavelengthGrid
) -> bool:
    """The mapping puts the profile's ends around the whole grid (within half a step)."""
    ends = mapping.wavelength_nm(np.array(pixel_range))
    tolerance = 0.5 * grid.step_nm
    return bool(ends.min() <= grid.start_nm + tolerance and ends.max() >= grid.stop_nm - tolerance)


def _covers(mapping: ExactMapping, pixel_range: tuple[float, float], grid: WavelengthGrid) -> None:
    if not _spans_grid(mapping, pixel_range, grid):
        ends = mapping.wavelength_nm(np.array(pixel_range))
        raise EstimationError(
            f"the best mapping puts the profile at {ends.min():.0f}–{ends.max():.0f} nm, not "
            f"covering the grid {grid.start_nm:g}–{grid.stop_nm:g} nm: does the profile hold the "
            "whole first order?"
        )


@one_blas_thread
def search_profiles(
    observations: LampObservation | Sequence[LampObservation],
    prior: CameraPrior,
    grid: WavelengthGrid,
    *,
    geometry: GratingPrior | None = None,
    starts: Sequence[QuadraticMapping] | None = None,
    kernel: FloatArray | None = None,
    orientation: Orientation = "auto",
    local_flexibility: float = LOCAL_FLEXIBILITY,
    ambiguity_delta_chi2: float | None = None,
) -> MappingSearch:
    """The pixel→wavelength mapping shared by one or more lamps' profiles (see the module docstring).

    Parameters
    ----------
    observations
        The lamps, all in one frame. Starts come from a fluorescent lamp's lines if there is one,
        else from the first lamp's correlation search (quadratic family) or from the grating
        prior (physical family); every lamp's profile enters the fits.
    prior
        The camera prior on ``grid``.
    grid
        Working grid; the mapping must cover it.
    geometry
        What the rig says about the grating (:func:`calib.wavelength.families.grating_prior`:
        line density, focal length in pixels, incidence). With profiles measured from the 0th
        order the search always uses the physical family (with a default prior when this is
        ``None``); with an arbitrary origin, giving it selects the physical family with the 0th
        order's position free.
    starts
        Starting mappings instead of the first stage's.
    kernel
        The camera's line spread in profile samples (default: the lamps' measured one).
    orientation
        ``"auto"`` tries both directions for profiles whose origin is arbitrary; profiles measured
        from the 0th order rise by construction.
    local_flexibility
        The basin-deciding stage's response flexibility.
    ambiguity_delta_chi2
        The tempered Δχ² below which a competing basin makes the result ambiguous (default
        :data:`AMBIGUITY_DELTA_CHI2`, or :data:`BROADBAND_AMBIGUITY_DELTA_CHI2` when no lamp has
        lines).

    Returns
    -------
    MappingSearch
    """
    lamps = [observations] if isinstance(observations, LampObservation) else list(observations)
    if not lamps:
        raise InputError("no lamp observations to find the mapping with", source="observations")
    frames = {(lamp.pixel[0], lamp.pixel[-1], lamp.n_pixels) for lamp in lamps}
    if len(frames) != 1:
        axes = "; ".join(
            f"{lamp.name}: px {lamp.pixel[0]:g}–{lamp.pixel[-1]:g}, {lamp.n_pixels} samples"
            for lamp in lamps
        )
        raise InputError(
            f"the lamps' profiles are on different pixel axes ({axes}); one mapping needs one "
            "axis: export every lamp's profile over the same pixels (one crop and geometry), or "
            "give the profiles in wavelength_nm",
            source="profiles",
        )
    lead = next((lamp for lamp in lamps if lamp.kind == "fluorescent"), lamps[0])
    pixel_range = (float(lead.pixel[0]), float(lead.pixel[-1]))
    from_spot = lead.pixel_origin == "direct_spot"
    physical = from_spot or geometry is not None
    directions = _directions(orientation, from_spot)
    if kernel is None:
        kernel = camera_kernel(lamps)

    # Starts (quadratic, in the profile's pixels) give the dispersion and, for the quadratic
    # family, the scan's centres.
    starts_per_direction = MAX_STARTS
    if starts:
        candidates = list(starts)
        origin = "given start"
    else:
        candidates = []
        origin = ""
        if lead.kind == "fluorescent":
            try:
                candidates = fluorescent_starts(
                    lead, prior.mean, grid, MAX_STARTS, explain_peaks=not physical
                )
                origin = f"lines of {lead.name}"
            except EstimationError:
                candidates = []
            if not physical:
                # Two line matches that explain the profile almost equally, beyond each other's
                # scan: both are scanned (decision 0188).
                if _second_match_scanned(candidates, pixel_range):
                    starts_per_direction = 2 * MAX_STARTS
                # A quadratic through a coarse table's lines extrapolates its node offsets
                # (decision 0121): the straight line through them starts the scan too.
                candidates = _with_linear_companions(candidates)
        if not candidates or (lead.kind != "fluorescent" and not physical):
            broadband = next((lamp for lamp in lamps if lamp.kind != "fluorescent"), lamps[0])
            candidates += _correlation_starts(broadband, prior, grid, directions)
            origin = origin or f"correlation search on {broadband.name}"
    candidates = [c for c in candidates if _direction(c, pixel_range) in directions]
    if not candidates:
        raise EstimationError(f"no starting mapping for lamp {lead.name!r} in {directions}")
    directions = _plausible_directions(candidates, directions, pixel_range)
    spacing = float(np.median(np.diff(lead.pixel)))
    dispersion = float(np.median(np.abs(candidates[0].dispersion_nm_per_px(lead.pixel))))
    nm_per_px = dispersion * spacing
    # Before the spectra are matched to the camera's resolution (which drops their bandwidth).
    scale_nm = spectrometer_scale_sigma_nm(lamps)
    measured = lamps
    line_lamps = [lamp for lamp in lamps if lamp.kind == "fluorescent"]
    unplaced_lines = bool(line_lamps) and all(map(lines_unplaced, line_lamps))
    lamps = [match_spectrometer(lamp, nm_per_px) for lamp in lamps]

    families: list[Family] = []
    if physical:
        base = geometry or default_prior(True)
        for direction in directions:
            families.append(
                GratingFamily(base, orientation=direction, axis_offset_px=base.axis_offset_px)
            )
    else:
        families.append(QuadraticFamily(pixel_range))

    built: dict[tuple[float, float, float, float, bool], StageFit] = {}

    def stage(
        family: Family,
        bin_nm: float,
        nodes: float,
        flexibility: float,
        floor: float,
        final: bool = False,
    ) -> StageFit:
        # The lamps' models do not depend on the family: build each resolution once.
        key = (bin_nm, nodes, flexibility, floor, final)
        if key not in built:
            # A stage on the same bins and nodes differs only in its prior and weights: it
            # shares that stage's layouts and lamp tables (decision 0135).
            like = next(
                (fit for other, fit in built.items() if other[:2] + other[4:] == key[:2] + key[4:]),
                None,
            )
            built[key] = _stage(
                lamps,
                family,
                grid,
                prior,
                bin_nm=bin_nm,
                nm_per_px=nm_per_px,
                kernel=kernel,
                node_step_nm=nodes,
                flexibility=flexibility,
                sigma_floor=floor,
                pixel_range=pixel_range,
                cut_ramps=final,
                like=like,
            )
        return replace(built[key], family=family)

    broadband_only = all(lamp.kind != "fluorescent" for lamp in lamps)
    # 1. Scan (binned, stiff prior, tempered noise); every local minimum of the grid is refined
    # on the scan's own coarse profile (cheap), the distinct results once more on a finer one.
    scanned: list[tuple[Family, Solution]] = []
    evaluations = 0

    def scan_grids(
        family: Family,
        scan: StageFit,
        grids: list[tuple[FloatArray, tuple[int, ...], FloatArray | None]],
    ) -> int:
        """Each grid's local minima refined (appended to ``scanned``); the evaluations made."""
        count = 0
        minima: list[tuple[float, FloatArray]] = []
        for points, shape, known in grids:
            # A physical scan's fine grid may come costed already (:func:`_physical_scan`).
            if known is None:
                costs = scan.costs(points)
                count += points.shape[0]
            else:
                costs = known
            # Each grid's own best minima: a grid around a poor start must not crowd out a
            # physically drawn one (or the other way round).
            minima += [
                (float(costs[i]), points[i]) for i in _local_minima(costs, shape)[:SCAN_MINIMA]
            ]
        minima.sort(key=lambda item: item[0])
        # A broadband quadratic scan refines only its few lowest distinct minima (decision 0115); a
        # line lamp's keep the number the hopeless rule (below) was judged with.
        refined_at_most = (
            BROADBAND_QUADRATIC_REFINED
            if broadband_only and isinstance(family, QuadraticFamily)
            else MAX_REFINED
        )
        refining = stage(family, GLOBAL_BIN_NM, COARSE_NODES_NM, FLEXIBILITY, GLOBAL_SIGMA_FLOOR)
        probe = np.linspace(pixel_range[0], pixel_range[1], 5)
        kept: list[FloatArray] = []
        for _, point in minima:
            # Neighbouring grid minima are one basin: refine it once.
            if any(
                np.max(np.abs(family.wavelengths(probe, point) - family.wavelengths(probe, other)))
                < QUADRATIC_SCAN[1]
                for other in kept
            ):
                continue
            kept.append(point)
            if len(kept) == min(SCAN_MINIMA * len(grids), refined_at_most):
                break
        for point in kept:
            so_far = min((s for _, s in scanned), key=lambda s: s.cost, default=None)
            # With a line lamp, a sketch whose own model ends hopelessly behind the best minimum
            # so far stops there: it would be skipped below, and is only costed in the deciding
            # stage (decision 0165).
            give_up = math.inf if broadband_only or so_far is None else hopeless_bar(so_far)
            solution = refining.sketch(point, give_up)
            leader = solution if so_far is None else so_far
            # With a line lamp, a minimum far behind the best one so far is no answer: its
            # local scan is skipped (it stays a candidate as refined).
            far_behind = not broadband_only and _behind(solution, leader) > HOPELESS_DELTA_CHI2
            if isinstance(family, QuadraticFamily) and not far_behind:
                # Finer around the refined point: a minimum a grid step away (the ends 4 nm
                # apart) may hold the lower basin, which the descent from the grid point missed.
                local, _ = _quadratic_points(family.mapping(solution.x), family, LOCAL_SCAN)
                local_costs = refining.costs(local)
                count += local.shape[0]
                best_local = local[int(np.argmin(local_costs))]
                if float(np.min(local_costs)) < solution.cost:
                    solution = refining.sketch(best_local)
            count += solution.evaluations
            scanned.append((family, solution))
        return count

    for family in families:
        scan = stage(family, SCAN_BIN_NM, SCAN_NODES_NM, FLEXIBILITY, GLOBAL_SIGMA_FLOOR)
        grids: list[tuple[FloatArray, tuple[int, ...], FloatArray | None]]
        if isinstance(family, QuadraticFamily):
            grids = [
                (*_quadratic_points(c, family), None)
                for c in _spread_starts(candidates, pixel_range, starts_per_direction)
            ]
        elif _rig_known(family):
            # The rig gives the line density and focal length: scan the prior itself (a
            # correlation search's linear starts miss a strongly curved first order).
            grids = [(*_prior_points(family), None)]
        elif "zero_order_px" in family.prior.fixed():
            # The 0th order is at a known pixel: the physics leaves the wavelengths at the
            # profile's ends and the incidence to scan. The correlation search's starts were up
            # to 110 nm off at the red end on validation cameras: the scan over every end the
            # result may take (coarse to fine) joins the end grids around them — unless a line
            # lamp's lines matched through the grating equation place it (decision 0097).
            same = [c for c in candidates if _direction(c, pixel_range) == family.orientation]
            grids, matched = _line_start_grids(family, same, lead, prior, grid, pixel_range)
            if not matched:
                physical_grids, count = _physical_scan(
                    scan, family, pixel_range, grid, PHYSICAL_FOLLOW if broadband_only else 0
                )
                evaluations += count
                grids += physical_grids
        else:
            same = [c for c in candidates if _direction(c, pixel_range) == family.orientation]
            grids = [
                (*_grating_points(family, c, pixel_range), None)
                for c in _spread_starts(same, pixel_range)
            ]
        evaluations += scan_grids(family, scan, grids)
    if not scanned:
        raise EstimationError("the mapping scan found no valid mapping")
    refined = scanned
    basins = _distinct(refined, pixel_range, MAX_BASINS)

    # 2. Decide between the basins on a finer profile with a flexible response.
    def deciding_stage(family: Family) -> StageFit:
        # The quadratic family decides with a flexible response (a broadband lamp's aliases: a
        # camera unlike the prior fits the wrong one better under the stiff prior); the physical
        # family's 0th order already rules out the shifts that the flexibility guards against,
        # and there the stiff prior is what tells a stretched rainbow from the right one.
        flexibility = local_flexibility if isinstance(family, QuadraticFamily) else FLEXIBILITY
        return stage(family, REFINE_BIN_NM, COARSE_NODES_NM, flexibility, 0.0)

    def decide(
        family: Family, solution: Solution, leader: Solution | None = None
    ) -> tuple[Solution, int]:
        """The deciding stage's descent from a scan basin (without :func:`deepen`); ``leader``,
        the best deciding descent so far."""
        deciding = deciding_stage(family)
        start = solution.x
        count = 0
        if isinstance(family, QuadraticFamily):
            # The flexible fit's basins are narrower than the stiff one's: scan its ends finely
            # around the stiff solution (one batched call) before descending.
            # Ranked on the scan refinement's profile with the same flexible response first; only
            # the lowest few are costed on the deciding one (decision 0115).
            local, _ = _quadratic_points(family.mapping(start), family, LOCAL_SCAN)
            ranking = stage(family, GLOBAL_BIN_NM, COARSE_NODES_NM, local_flexibility, 0.0)
            local_costs, costed = _shortlisted_costs(local, ranking, deciding, DECIDING_SHORTLIST)
            count += costed
            lowest = int(np.argmin(local_costs))
            start = local[lowest]
            # The grid's middle point is the basin's own (through the mapping and back: equal
            # up to rounding, so ``solution.x`` itself is not compared; decision 0150).
            from_own = lowest == local.shape[0] // 2
        else:
            from_own = True
        # The descent runs to its end, however far behind the best one so far it starts: its
        # Gauss–Newton model at a start far from its minimum does not say where it ends, and a
        # descent stopped on it dropped the basin the likelihood prefers (decision 0170).
        outcome = deciding.descend(start)
        count += outcome.evaluations
        if (
            broadband_only
            and isinstance(family, QuadraticFamily)
            and not from_own
            and (leader is None or _behind(outcome, leader) <= HOPELESS_DELTA_CHI2)
        ):
            # A broadband lamp alone: the scan's lowest point may lie in a neighbouring minimum a
            # few nanometres away (Nikon D1x, decision 0139). The descent from the basin's own
            # point is weighed too, and kept when the scan's stands behind it by the search's
            # bar (decision 0141: kept whenever lower, two noisy scenes moved to a wrong one).
            # Not for a basin whose descent stands hopelessly behind the best one so far, as its
            # scan about it is skipped (decisions 0076, 0143).
            own = deciding.descend(solution.x)
            count += own.evaluations
            if _behind(outcome, own) > AMBIGUITY_DELTA_CHI2:
                outcome = own
        return outcome, count

    def deepen(family: Family, outcome: Solution) -> tuple[Solution, int]:
        """The deciding descent's result, or a lower minimum a few nanometres from it."""
        if not (broadband_only and isinstance(family, GratingFamily) and not _rig_known(family)):
            return outcome, 0
        # The finer profile splits a scan basin into minima a few nanometres apart (the
        # broadband profile's ripple against the prior's shape): scan the ends around the
        # descent's result (one batched call) and descend again from a lower point. (A rig that
        # gives the whole geometry — a grating file's — is scanned over its prior.)
        deciding = deciding_stage(family)
        local = _local_end_points(family, outcome.x, pixel_range)
        local_costs, count = _shortlisted_costs(
            local,
            stage(family, GLOBAL_BIN_NM, COARSE_NODES_NM, FLEXIBILITY, GLOBAL_SIGMA_FLOOR),
            deciding,
            DEEPEN_SHORTLIST,
        )
        if np.any(np.isfinite(local_costs)) and float(np.min(local_costs)) < outcome.cost:
            again = deciding.descend(local[int(np.argmin(local_costs))])
            count += again.evaluations
            if again.cost < outcome.cost and not _stretched(family, again.x, measured[0], prior):
                outcome = again
        return outcome, count

    decided: list[tuple[Family, Solution]] = []
    hopeless: list[tuple[Family, Solution]] = []
    for family, solution in basins:
        # Lines pin the mapping: a basin far behind the scan's best is only costed in the
        # deciding stage (below). The first basin is the scan's best, never hopeless.
        if not broadband_only and _behind(solution, basins[0][1]) > HOPELESS_DELTA_CHI2:
            hopeless.append((family, solution))
            continue
        outcome, count = decide(
            family, solution, min((o for _, o in decided), key=lambda o: o.cost, default=None)
        )
        evaluations += count
        decided.append((family, outcome))
    # Every basin's descent first, then the scan about each one (:func:`deepen`) unless it is
    # hopelessly behind the best of them, as a line lamp's scan basins are (decision 0065): on
    # the validation split (235 cameras with the predicted ones, LED only with and without EXIF)
    # 4 of 470 answers moved, within noise, for ~10 % of an LED-only estimate (decision 0076).
    leader = min((outcome for _, outcome in decided), key=lambda outcome: outcome.cost)
    for index, (family, outcome) in enumerate(decided):
        if _behind(outcome, leader) > HOPELESS_DELTA_CHI2:
            continue
        deepened, count = deepen(family, outcome)
        evaluations += count
        decided[index] = (family, deepened)
    for family, solution in hopeless:
        # Costed where the scan's refinement left it (a candidate in the result); refined as the
        # others only when it is not still that far behind the deciding stage's best, or when
        # that best falls short of the grid (the answer is then chosen among the rest).
        leading_family, leading = min(decided, key=lambda item: item[1].cost)
        outcome = replace(solution, cost=float(deciding_stage(family).costs(solution.x[None])[0]))
        evaluations += 1
        if not (
            _behind(outcome, leading) > HOPELESS_DELTA_CHI2
            and _spans_grid(leading_family.mapping(leading.x), pixel_range, grid)
        ):
            outcome, count = decide(family, solution)
            evaluations += count
            outcome, count = deepen(family, outcome)
            evaluations += count
        decided.append((family, outcome))
    # The scan's best basin as the deciding stage left it (broadband lamps alone: every basin is
    # decided, in the scan's order).
    scan_best = decided[0][1]
    stalled_evaluations = 0
    # Basins that the finer fit merged are one.
    decided = _distinct(decided, pixel_range, MAX_BASINS)
    if broadband_only and isinstance(decided[0][0], QuadraticFamily):
        # A valley narrower than the deciding scan's step (decision 0145).
        ranking = stage(decided[0][0], GLOBAL_BIN_NM, COARSE_NODES_NM, local_flexibility, 0.0)
        last = stage(decided[0][0], FINAL_BIN_NM, FINE_NODES_NM, FLEXIBILITY, 0.0, final=True)
        decided, count = hidden_valleys(
            decided, ranking, deciding_stage(decided[0][0]), last, pixel_range
        )
        evaluations += count
        # An end too far out, the truth's valley inwards of it (decision 0152).
        decided, count = end_probes(
            decided, ranking, deciding_stage(decided[0][0]), last, pixel_range
        )
        evaluations += count
        # The same about the scan's best basin when its deciding descent stalled (decision 0158).
        decided, count = stalled_probe(
            decided, scan_best, ranking, deciding_stage(decided[0][0]), last, pixel_range
        )
        evaluations += count
        stalled_evaluations = count
        # A whole-mapping alias of the leader (decision 0158).
        decided, count = whole_shift_probe(
            decided, ranking, deciding_stage(decided[0][0]), last, pixel_range
        )
        evaluations += count
    if unplaced_lines and isinstance(decided[0][0], QuadraticFamily):
        # Line lamps whose spectra cannot place their lines (coarse tables, decision 0121) hold
        # the mapping only to their lines' nodes, and nothing holds the quadratic's red end
        # past them: the deciding profile has minima there a few nanometres apart that the
        # scan's basins miss (decision 0149). Descents from the best basin with its red end
        # moved by the local scan's reach weigh them: kept as candidates, the answer if lower.
        family, outcome = decided[0]
        red = int(np.argmax(family.wavelengths(np.array(pixel_range), outcome.x)))
        red_index = 0 if red == 0 else len(outcome.x) - 1
        deciding = deciding_stage(family)
        for shift in RED_END_PROBE_NM:
            start = outcome.x.copy()
            start[red_index] += shift
            # A probe whose own model ends hopelessly behind the basin probed stops there: far
            # behind, it weighs nothing in the result (decision 0165).
            probed = deciding.descend(start, hopeless_bar(outcome))
            evaluations += probed.evaluations
            decided.append((family, probed))
        decided = _distinct(decided, pixel_range, MAX_BASINS)
    # A profile holds the whole first order: the best basin that spans the grid is the answer (a
    # test camera's best basin ended at 688 nm and the estimate failed); the others stay
    # candidates, and with none spanning it the check below says so.
    decided.sort(key=lambda item: not _spans_grid(item[0].mapping(item[1].x), pixel_range, grid))
    family, best = decided[0]
    # 3. Final: finer nodes, the stiff prior, the profile at ≤ FINAL_BIN_NM per sample.
    # (Its cost continuous where the hats are cut: a fit converging to its last digits stalls
    # on the jump; decision 0124.)
    final_stage = stage(family, FINAL_BIN_NM, FINE_NODES_NM, FLEXIBILITY, 0.0, final=True)
    final = final_stage.settle(best.x)
    evaluations += final.evaluations
    exact = family.mapping(final.x)
    # A broadband lamp alone leaves the mapping to the camera prior's shape: a camera unlike the
    # prior's mean pulls it by what the curvature cannot see (lines pin it: no such term).
    edge = red_edge_nm(measured[0], exact, prior) if broadband_only and physical else None
    pulled: ExactMapping | None = None
    stretched = edge is not None and edge[0] - edge[1] > RED_EDGE_MARGIN_NM
    if (
        edge is not None
        and isinstance(family, GratingFamily)
        and (stretched or not _rig_known(family))
    ):
        # The red end stretched beyond where the prior ends the signal: a basin the likelihood
        # may prefer with no other competing. The basin with the red end pulled in to the prior's
        # edge is weighed too (and taken when it fits better: the scan missed it). Not
        # stretched, the red end pulled in further than the prior's own edge (a camera whose
        # signal ends early, e.g. behind a colour filter) is weighed the same way: the scan's
        # coarse profile leans on the prior's edge and misses that basin (decision 0085).
        deciding = stage(family, REFINE_BIN_NM, COARSE_NODES_NM, FLEXIBILITY, 0.0)
        targets = None if stretched else [edge[0] - pull for pull in RED_EDGE_PULL_IN_NM]
        points = _pulled_in(family, final.x, pixel_range, edge, targets)
        costs = deciding.costs(points)
        evaluations += points.shape[0]
        if np.any(np.isfinite(costs)):
            outcome = deciding.descend(points[int(np.argmin(costs))])
            evaluations += outcome.evaluations
            probe9 = np.linspace(pixel_range[0], pixel_range[1], 9)
            if np.isfinite(outcome.cost) and all(
                np.max(np.abs(f.wavelengths(probe9, o.x) - family.wavelengths(probe9, outcome.x)))
                > AMBIGUITY_MIN_DISTANCE_NM
                for f, o in decided
            ):
                taken = None
                if outcome.cost < decided[0][1].cost:
                    taken = final_stage.settle(outcome.x)
                    evaluations += taken.evaluations
                    # A profile holds the whole first order: a basin short of the grid is no
                    # answer (it stays a candidate).
                    if not _spans_grid(family.mapping(taken.x), pixel_range, grid):
                        taken = None
                if taken is not None:
                    decided = [(family, outcome), *decided]
                    final = taken
                    exact = family.mapping(final.x)
                    edge = red_edge_nm(measured[0], exact, prior)
                elif stretched:
                    decided = [*decided, (family, outcome)]
                    pulled = family.mapping(outcome.x)
                # Not stretched and fitting worse, the pulled-in basin is no candidate: on the
                # validation split each one kept warned a right mapping (8 of 304 scenes, none
                # of the wrong ones; decision 0085).
    _covers(exact, pixel_range, grid)

    # Ambiguity: every basin's profile likelihood, tempered by the misfit of the best one.
    best_cost = decided[0][1].cost
    temper = decided[0][1].temper
    probe = np.linspace(pixel_range[0], pixel_range[1], 64)
    exact_probe = exact.wavelength_nm(probe)
    candidates_out = []
    for index, (basin_family, outcome) in enumerate(decided):
        delta = (outcome.cost - best_cost) / temper
        mapping = exact if index == 0 else basin_family.mapping(outcome.x)
        distance = float(np.sqrt(np.mean((mapping.wavelength_nm(probe) - exact_probe) ** 2)))
        candidates_out.append(
            Candidate(
                mapping,
                outcome.cost,
                float(delta),
                float(math.exp(-0.5 * delta / BASIN_TEMPER)),
                distance,
            )
        )
    covariance = final.covariance()
    ends: tuple[EndProfile, ...] = ()
    if broadband_only and not isinstance(family, GratingFamily):
        # The curvature states the ends' valley as a parabola; the likelihood itself says how
        # far they move (decision 0155).
        covariance, ends = end_profile(final_stage, final.x, covariance, final.cost / final.dof)
        evaluations += 1 + 2 * len(ends) if ends else 0
    mapping, local_rms = _report(exact, family, final.x, covariance, pixel_range, origin)
    if ambiguity_delta_chi2 is None:
        ambiguity_delta_chi2 = (
            BROADBAND_AMBIGUITY_DELTA_CHI2 if broadband_only else AMBIGUITY_DELTA_CHI2
        )
    coarse = None
    if broadband_only and isinstance(family, GratingFamily):
        # The basins were found on a coarser profile of the same model: an answer that view
        # rejects is not decided by the finer one's Δχ² (decision 0118, calib.wavelength.
        # coarse_check); its best basin becomes a candidate and σ reaches it. How far behind it
        # the answer stands also sizes the prior's pull (decision 0128).
        coarse = coarse_view(
            stage(family, GLOBAL_BIN_NM, COARSE_NODES_NM, FLEXIBILITY, GLOBAL_SIGMA_FLOOR).costs,
            final.x,
            [
                (solution.x, solution.dof)
                for basin_family, solution in basins
                if basin_family is family
            ],
            lambda x: float(np.sqrt(np.mean((family.wavelengths(probe, x) - exact_probe) ** 2))),
            min_distance_nm=AMBIGUITY_MIN_DISTANCE_NM,
            threshold=AMBIGUITY_DELTA_CHI2,
        )
    sigma = basin_sigma(
        candidates_out,
        local_nm=LOCAL_SIGMA_SCALE * local_rms,
        scale_nm=scale_nm,
        misfit_nm=prior_misfit_sigma_nm(
            temper, local_rms, 0.0 if coarse is None else coarse.delta_chi2
        )
        if broadband_only
        else 0.0,
        ambiguity_delta_chi2=ambiguity_delta_chi2,
    )
    ambiguous = sigma.competing is not None
    stated = sigma.stated_nm
    warnings: list[str] = []
    if edge is not None and edge[0] - edge[1] > RED_EDGE_MARGIN_NM:
        # A stretched red end: no basin competes, so the likelihood cannot say (decision 0049).
        # σ spans the excess and, when it was weighed, the basin with the red end pulled in.
        ambiguous = True
        stated = max(stated, edge[0] - edge[1])
        other_basin = ""
        if pulled is not None:
            apart = float(np.sqrt(np.mean((pulled.wavelength_nm(probe) - exact_probe) ** 2)))
            stated = max(stated, 0.5 * apart)
            other_basin = (
                f"; the basin with the red end pulled in to it fits worse, {apart:.1f} nm away "
                "(RMS), and is among the result's candidates"
            )
        warnings.append(
            f"the mapping may be stretched at the red end: it puts the end of {measured[0].name}'s "
            f"signal (where it falls to {RED_EDGE_FRACTION:.0%} of its peak) at {edge[0]:.0f} nm, "
            f"{edge[0] - edge[1]:.0f} nm beyond where the camera prior's mean puts it "
            f"({edge[1]:.0f} nm; more than {RED_EDGE_MARGIN_NM:g} nm is beyond nearly every "
            f"validation camera){other_basin}; the stated σ ({stated:.1f} nm) spans both. "
            + deciding_shot(lamps)
        )
    if broadband_only and temper > MISFIT_WARN_TEMPER:
        # The camera is unlike the prior: the likelihood that ranked the basins is misspecified,
        # so a basin it put Δχ² in the hundreds behind may still be the truth (decision 0054).
        ambiguous = True
        others = [c.distance_nm for c in candidates_out[1:]]
        nearest = min(others) if others else 0.0
        stated = max(stated, 0.5 * nearest)
        widened = (
            f"; the nearest other basin, {nearest:.1f} nm away (RMS), is among the result's "
            f"candidates and the stated σ ({stated:.1f} nm) reaches half-way to it"
            if others
            else f"; no other basin was found, the stated σ ({stated:.1f} nm) holds the misfit"
        )
        warnings.append(
            f"the camera prior fits {measured[0].name}'s profile badly (reduced χ² {temper:.1f}, "
            f"above {MISFIT_WARN_TEMPER:g}): with a broadband lamp alone the mapping leans on the "
            f"prior's shape, and the basins' likelihoods cannot be trusted{widened}. "
            + deciding_shot(lamps)
        )
    for end in ends:
        if end.delta_chi2 >= END_PROFILE_WARN_DELTA_CHI2:
            continue
        # The likelihood does not hold this end within the step: nothing but the camera prior's
        # shape places it (decision 0155).
        ambiguous = True
        colour = "blue" if final.x[end.index] <= final.x[len(final.x) - 1 - end.index] else "red"
        warnings.append(
            f"the mapping's {colour} end is not held: moving it by {END_PROFILE_STEP * end.sigma_nm:.1f} "
            f"nm ({END_PROFILE_STEP:g} of its curvature σ) raises the fit's Δχ² by "
            f"{max(end.delta_chi2, 0.0):.1f} (below {END_PROFILE_WARN_DELTA_CHI2:g}): with "
            f"{measured[0].name}'s light fading there the end rests on the camera prior's shape; the "
            f"stated σ ({stated:.1f} nm) is the likelihood's own there. " + deciding_shot(lamps)
        )
    if coarse is not None and coarse.rejects:
        cost = float(deciding_stage(family).costs(coarse.x[None])[0])
        delta = (cost - best_cost) / temper
        candidates_out.append(
            Candidate(
                family.mapping(coarse.x),
                cost,
                float(delta),
                float(math.exp(-0.5 * delta / BASIN_TEMPER)) if math.isfinite(delta) else 0.0,
                coarse.distance_nm,
            )
        )
        ambiguous = True
        stated = max(stated, 0.5 * coarse.distance_nm)
        warnings.append(
            f"the mapping is ambiguous: on the coarser profile ({GLOBAL_BIN_NM:g} nm bins) where "
            f"the search found its basins, the same model puts its best basin {coarse.distance_nm:.1f} "
            f"nm away (RMS) and this answer Δχ² {coarse.delta_chi2:.0f} behind it (above "
            f"{AMBIGUITY_DELTA_CHI2:g}): the camera prior describes {measured[0].name}'s "
            "camera too poorly for the finer fit to decide; both are in the result and the stated "
            f"σ ({stated:.1f} nm) spans them. " + deciding_shot(lamps)
        )
    mapping = stated_covariance(mapping, stated, scale_nm, pixel_range)
    if sigma.competing is not None:
        other = sigma.competing
        how = f"tempered Δχ² {other.delta_chi2:.1f}"
        warnings.append(
            f"the mapping is ambiguous: a second basin {other.distance_nm:.1f} nm away (RMS) fits "
            f"almost as well ({how}; ambiguous below {ambiguity_delta_chi2:g}); both are in the "
            f"result and the stated σ ({stated:.1f} nm) spans them. "
            + deciding_shot(lamps, bandwidth_hint=True)
        )
    spread_nm = sigma.spread_nm
    details = {
        **dict(mapping.details),
        "mapping_lamps": [lamp.name for lamp in lamps],
        "origin": origin,
        "family": "grating" if isinstance(family, GratingFamily) else "quadratic",
        "orientation": "rising" if _direction_of(exact, pixel_range) > 0 else "falling",
        "n_starts": len(candidates),
        "evaluations": evaluations,
        "stalled_probe_evaluations": stalled_evaluations,
        "final_cost": final.cost,
        "reduced_chi2": final.cost / final.dof,
        "temper": temper,
        "basin_spread_nm": spread_nm,
        "local_rms_nm": local_rms,
        "spectrometer_scale_sigma_nm": scale_nm,
        "prior_misfit_sigma_nm": sigma.misfit_nm,
        "ambiguous": ambiguous,
        "ambiguity_delta_chi2": ambiguity_delta_chi2,
        "coarse_view": None
        if coarse is None
        else {
            "delta_chi2": coarse.delta_chi2,
            "distance_nm": coarse.distance_nm,
            "rejects": coarse.rejects,
        },
        "red_edge_nm": None if edge is None else {"profile": edge[0], "prior_mean": edge[1]},
        "end_profile": [end.to_dict() for end in ends],
        "candidates": [c.to_dict(pixel_range) for c in candidates_out],
        "flexibility": FLEXIBILITY,
        "local_flexibility": local_flexibility,
    }
    if isinstance(family, GratingFamily):
        details["grating_prior"] = {
            "source": family.prior.source,
            "values": {k: list(v) for k, v in family.prior.values.items()},
        }
    mapping = mapping.with_details(wavelength_rms_nm=stated, details=details)
    return MappingSearch(
        mapping=mapping,
        exact=exact,
        candidates=tuple(candidates_out),
        ambiguous=ambiguous,
        warnings=tuple(warnings),
        details=details,
    )


#: The red edge of a broadband lamp's profile: where its summed signal falls to this fraction of
#: its peak, and how far (nm) beyond the camera prior mean's edge under the lamp's spectrum a
#: mapping may put it before it is flagged as stretched. Chosen on the validation split only
#: (decision 0049): over 377 of Solomatov & Akkaynak's predicted curves (LED only, seed 0) the true
#: edge lies −24…+8.3 nm from the prior mean's; every mapping > 3 nm off put it 9–30 nm beyond,
#: 3 of the 358 right ones more than 8 nm. Lowered to 6 by decision 0054 (validation split, two
#: seeds, 846 scenes): the failures of cameras whose cut-off lies 8–12 nm *below* the prior's were
#: stretched to 6.1–7.7 nm beyond it, unwarned; 6 warns on 4.6–5.8 % of the right mappings (8:
#: 3.9 %).
RED_EDGE_FRACTION = 0.03
RED_EDGE_MARGIN_NM = 6.0
#: Sampling (nm) of the prior mean's edge.
RED_EDGE_STEP_NM = 0.5
#: Incidence offsets (°) about a basin's at which a red end pulled in is tried.
PULLED_IN_INCIDENCE_DEG = (-4.0, 0.0, 4.0)
#: How far (nm) below the found mapping's red edge a red end pulled in is tried when the edge is
#: not stretched: the physical scan's end step (:data:`PHYSICAL_STEP_NM`) up to 40 nm, where a
#: camera behind a colour filter (a Wratten-80-like step at 560–580 nm) ends its signal 20–40 nm
#: below the prior mean's edge; the descent from the best of them finds the minimum between.
RED_EDGE_PULL_IN_NM = tuple(PHYSICAL_STEP_NM * k for k in (1, 2, 3, 4))


def red_edge_nm(
    lamp: LampObservation, mapping: ExactMapping, prior: CameraPrior
) -> tuple[float, float, float] | None:
    """The red edge of ``lamp``'s profile under ``mapping`` and the camera prior mean's edge under
    the lamp's spectrum (nm; :data:`RED_EDGE_FRACTION`), and the profile's edge pixel, or ``None``
    when the profile has no signal or the prior's edge is not inside the working grid (nothing to
    compare).

    A broadband lamp alone leaves the mapping's red end to where the camera's signal ends; with the
    0th order pinned, stretching the red end by 20–35 nm is a basin the likelihood can prefer for a
    camera unlike the prior (no competing basin then warns). Where the signal ends is the camera's
    IR cut-off under the lamp, which the prior knows within a few nanometres.
    """
    signal = np.sum(np.clip(np.asarray(lamp.profile, dtype=np.float64), 0.0, None), axis=1)
    peak = float(np.max(signal)) if signal.size else 0.0
    if peak <= 0:
        return None
    wavelengths = np.asarray(mapping.wavelength_nm(lamp.pixel), dtype=np.float64)
    above = np.flatnonzero(signal >= RED_EDGE_FRACTION * peak)
    reddest = int(above[np.argmax(wavelengths[above])])
    profile_edge = float(wavelengths[reddest])
    grid = prior.grid.wavelength_nm
    fine = np.arange(grid[0], grid[-1] + 0.5 * RED_EDGE_STEP_NM, RED_EDGE_STEP_NM)
    mean = np.sum([np.interp(fine, grid, prior.mean[:, c]) for c in range(3)], axis=0)
    expected = mean * np.asarray(lamp.spectrum.at(fine), dtype=np.float64)
    if not np.any(expected > 0):
        return None
    prior_edge = float(np.max(fine[expected >= RED_EDGE_FRACTION * np.max(expected)]))
    if prior_edge >= fine[-1]:
        return None
    return profile_edge, prior_edge, float(lamp.pixel[reddest])


def _pulled_in(
    family: GratingFamily,
    x: FloatArray,
    pixel_range: tuple[float, float],
    edge: tuple[float, float, float],
    targets_nm: Sequence[float] | None = None,
) -> FloatArray:
    """Gratings (one per :data:`PULLED_IN_INCIDENCE_DEG` offset about ``x``'s incidence, for each
    target) whose red end is pulled in so that the profile's red edge lands on a target (default:
    the prior mean's edge, ``edge[1]``): the stretch grows from the blue end, so the red end moves
    by the edge's excess scaled to the whole profile."""
    ends = family.wavelengths(np.array(pixel_range), x)
    red = 1 if ends[1] > ends[0] else 0
    blue_px, red_px = pixel_range[1 - red], pixel_range[red]
    targets = np.array([edge[1]] if targets_nm is None else list(targets_nm), dtype=np.float64)
    moved = (edge[0] - targets) * (red_px - blue_px) / (edge[2] - blue_px)
    wanted = np.repeat(ends[None, :], targets.size, axis=0)
    wanted[:, red] -= moved
    incidence = float(x[family.names.index("incidence_deg")])
    points = _end_points(
        family,
        pixel_range,
        wanted[:, 0],
        wanted[:, 1],
        [incidence + k for k in PULLED_IN_INCIDENCE_DEG],
    )
    return points.reshape(-1, points.shape[-1])


#: A direction whose best correlation start scores this far below the best one is not searched
#: (the correlation of a profile with its mirror image is poor; the margin keeps close calls).
DIRECTION_MARGIN = 0.05


def _plausible_directions(
    candidates: Sequence[QuadraticMapping],
    directions: tuple[int, ...],
    pixel_range: tuple[float, float],
) -> tuple[int, ...]:
    """The directions whose correlation starts are near the best (all when scores are missing)."""
    scores = dict.fromkeys(directions, -np.inf)
    for candidate in candidates:
        score = candidate.details.get("ncc")
        if score is None:
            return directions
        direction = _direction(candidate, pixel_range)
        scores[direction] = max(scores[direction], float(score))
    best = max(scores.values())
    return tuple(d for d in directions if scores[d] >= best - DIRECTION_MARGIN)


def _with_linear_companions(starts: Sequence[QuadraticMapping]) -> list[QuadraticMapping]:
    """Each line-matched start followed by the straight line through its matched lines.

    A quadratic through a table's lines extrapolates their node offsets (a 5 nm table's 580 nm
    node where the camera's peak is at 577) into tens of nm at the profile's red end, beyond the
    scan's end grid (:data:`QUADRATIC_SCAN`); the straight line through the same lines is a start
    of the correlation search's kind (decision 0121: the validation split's Leica M8 FL2 paper
    scene, 2.5 nm off from such a start, lands 0.03 nm off from its straight companion). With
    :data:`MAX_STARTS` per direction, the best match and its companion are the ones scanned."""
    out: list[QuadraticMapping] = []
    for start in starts:
        out.append(start)
        matched = start.details.get("matched") or []
        if len(matched) < 3 or start.a == 0.0:
            continue
        pixel = np.array([float(m["pixel"]) for m in matched])
        line_nm = np.array([float(m["line_nm"]) for m in matched])
        try:
            straight = QuadraticMapping.fit(pixel, line_nm, method="fluorescent-peaks", degree=1)
        except EstimationError:
            continue
        out.append(
            QuadraticMapping(
                straight.a,
                straight.b,
                straight.c,
                method="fluorescent-peaks",
                pixel_range=start.pixel_range,
            )
        )
    return out


def _second_match_scanned(
    matches: Sequence[QuadraticMapping], pixel_range: tuple[float, float]
) -> bool:
    """Whether a line lamp's second match (:func:`calib.wavelength.peaks.match_peak_hypotheses`,
    best first) is scanned too: it scores within :data:`SECOND_MATCH_SCORE` of the first and
    lies beyond the scan's reach (:data:`QUADRATIC_SCAN`) of the first and its straight
    companion at an end of the profile, so no grid about them holds its basin."""
    if len(matches) < 2:
        return False
    first, second = matches[0], matches[1]
    if float(second.details.get("score", 0.0)) < SECOND_MATCH_SCORE * float(
        first.details.get("score", np.inf)
    ):
        return False
    ends = np.array(pixel_range)
    return all(
        np.max(np.abs(second.wavelength_nm(ends) - near.wavelength_nm(ends))) > QUADRATIC_SCAN[0]
        for near in _with_linear_companions([first])
    )


def _spread_starts(
    candidates: Sequence[QuadraticMapping],
    pixel_range: tuple[float, float],
    per_direction: int = MAX_STARTS,
) -> list[QuadraticMapping]:
    """At most ``per_direction`` per direction, each a scan step away from the ones before."""
    kept: list[QuadraticMapping] = []
    ends = np.array(pixel_range)
    for candidate in candidates:
        same = [k for k in kept if _direction(k, pixel_range) == _direction(candidate, pixel_range)]
        if len(same) >= per_direction:
            continue
        if all(
            np.max(np.abs(candidate.wavelength_nm(ends) - k.wavelength_nm(ends)))
            > QUADRATIC_SCAN[1]
            for k in same
        ):
            kept.append(candidate)
    return kept


def _directions(orientation: Orientation, from_spot: bool) -> tuple[int, ...]:
    if orientation == "rising" or from_spot:
        return (1,)
    if orientation == "falling":
        return (-1,)
    if orientation != "auto":
        raise InputError(
            f"orientation must be 'auto', 'rising' or 'falling', got {orientation!r}",
            source="orientation",
        )
    return (1, -1)


def _direction_of(mapping: ExactMapping, pixel_range: tuple[float, float]) -> int:
    ends = mapping.wavelength_nm(np.array(pixel_range))
    return 1 if ends[1] >= ends[0] else -1


def _direction(mapping: QuadraticMapping, pixel_range: tuple[float, float]) -> int:
    return _direction_of(mapping, pixel_range)


def _correlation_starts(
    observation: LampObservation,
    prior: CameraPrior,
    grid: WavelengthGrid,
    directions: tuple[int, ...],
) -> list[QuadraticMapping]:
    """Linear starts from the normalised cross-correlation, on a profile binned to ~1 nm."""
    from calib.wavelength.peaks import (
        coarse_mapping_candidates,
        model_curve_on_fine_axis,
        nominal_dispersion,
    )

    axis, model = model_curve_on_fine_axis(observation.spectrum, prior.mean, grid)
    nominal = nominal_dispersion(observation.pixel, observation.profile, axis, model)
    # ~1.5 nm bins and 48 dispersions find starts as good as the full profile with 96 (the scan
    # that follows covers their error) at a sixth of the cost.
    factor = max(1, int(1.5 / max(nominal, 1e-9)))
    binned = bin_pixels(observation, factor)
    return coarse_mapping_candidates(
        binned.pixel,
        binned.profile,
        axis,
        model,
        grid=grid,
        n_candidates=3 * len(directions),
        n_dispersions=48,
        allow_reversed=-1 in directions,
    )


#: A measured lamp spectrum sampled or measured coarser than this (nm) cannot place a fluorescent
#: lamp's lines: it holds them at its nodes, 1–2 nm from a camera line's centre.
COARSE_SPECTRUM_NM = 2.0


def coarse_spectrum(observation: LampObservation, limit_nm: float = COARSE_SPECTRUM_NM) -> bool:
    """The lamp's spectrum is sampled, or was measured with a bandwidth, coarser than
    ``limit_nm``."""
    step = float(np.median(np.diff(observation.spectrum.wavelength_nm)))
    bandwidth = observation.spectrum_bandwidth_nm or 0.0
    return max(step, bandwidth) > limit_nm


def lines_unplaced(lamp: LampObservation) -> bool:
    """A line lamp's spectrum cannot place its lines: a coarse table nobody measured (no stated
    bandwidth, e.g. colour-science's 5 nm FL tables) holds them at its nodes, not their
    wavelengths (decisions 0121, 0149)."""
    return lamp.spectrum_bandwidth_nm is None and coarse_spectrum(lamp)


def deciding_shot(lamps: Sequence[LampObservation], *, bandwidth_hint: bool = False) -> str:
    """The advice closing an ambiguity warning: what would decide the mapping, given what was
    shot (decision 0122). Without a line lamp: a fluorescent (line) lamp. With one whose spectrum
    is a coarse table or has no stated bandwidth: its spectrum measured with a bandwidth (or its
    built-in line list), another lamp's lines, or the 0th order. With a finely measured one:
    another line lamp with other lines, or the 0th order. The 0th order is not asked for when the
    profiles' origin is already the direct spot."""
    line_lamps = [lamp for lamp in lamps if lamp.kind == "fluorescent"]
    spot = any(lamp.pixel_origin == "direct_spot" for lamp in lamps)
    zeroth = "" if spot else ", or the grating's 0th order (direct spot) in the frame"
    if not line_lamps:
        hint = " (or a lamp spectrum measured at a narrower bandwidth)" if bandwidth_hint else ""
        return f"A fluorescent (line) lamp shot in the same geometry{hint} decides it."
    names = ", ".join(lamp.name for lamp in line_lamps)
    others = (
        "a second line lamp with other lines (a neon lamp, or a tri-phosphor CFL's Eu 611 nm) "
        "in the same geometry"
    )
    coarse = [
        lamp for lamp in line_lamps if lamp.spectrum_bandwidth_nm is None or coarse_spectrum(lamp)
    ]
    if coarse:
        return (
            f"The line lamp {names} was in the scene, but its spectrum is too coarse or has no "
            "stated bandwidth to place its lines: its spectrum measured with a stated bandwidth "
            f"of ≤ {COARSE_SPECTRUM_NM:g} nm (or its built-in line list: --spectrum builtin:hg, "
            "builtin:cfl-triphosphor), "
            f"{others}{zeroth} decides it."
        )
    return f"The line lamp {names} was in the scene and did not decide it: {others}{zeroth} decides it."


def spectrometer_scale_sigma_nm(
    lamps: Sequence[LampObservation], *, placed_by_features: bool = False
) -> float:
    """σ (nm) the mapping inherits from the lamp spectra's wavelength scale: a spectrum measured by a
    spectrometer (its bandwidth stated) is :data:`SPECTROMETER_SCALE_SIGMA_NM` off as a whole,
    or the σ its Hg-line check left (``metadata["wavelength_scale_sigma_nm"]``,
    :mod:`calib.core.spectrometer_scale`, decision 0069); a tabulated one (no bandwidth:
    colour-science's tables, a built-in line list) adds nothing. The largest of the lamps'.

    A mapping placed by lines or dips of the spectra (``placed_by_features``) or found with a
    fluorescent (line) or narrowband lamp follows that offset whole. One found from broadband lamps alone takes
    up :data:`BROADBAND_SCALE_TRANSFER` of it (measured, decision 0108); the rest moves the spectra
    against the mapping and is re-solved in the sensitivity's σ budget
    (:func:`calib.methods.uncertainty.spectrometer_sigma`, decision 0117)."""
    sigmas = [
        SPECTROMETER_SCALE_SIGMA_NM if (checked := scale_sigma_nm(lamp)) is None else checked
        for lamp in lamps
        if lamp.spectrum_bandwidth_nm is not None
    ]
    full = max(sigmas, default=0.0)
    # A narrowband LED's peak is a feature its spectrum places, like a line: the transfer was
    # measured on a white LED only, so such a lamp keeps the whole term.
    if placed_by_features or any(lamp.kind in ("fluorescent", "narrowband") for lamp in lamps):
        return full
    return BROADBAND_SCALE_TRANSFER * full


def stated_covariance(
    mapping: QuadraticMapping, stated_nm: float, scale_nm: float, pixel_range: tuple[float, float]
) -> QuadraticMapping:
    """The report form's coefficient covariance made to state ``stated_nm`` (RMS over the profile):
    the local part scaled (the prior's pull, the basins' spread) plus a common offset of
    ``scale_nm`` (the spectrometer's wavelength scale shifts every wavelength alike)."""
    if mapping.covariance is None:
        return mapping
    local = np.asarray(mapping.covariance, dtype=np.float64)
    local_nm = wavelength_rms_from_covariance(local, pixel_range)
    wanted = max(stated_nm**2 - scale_nm**2, 0.0)
    scaled = local * (wanted / local_nm**2 if local_nm > 0 else 1.0)
    scaled[2, 2] += scale_nm**2
    return mapping.with_details(
        covariance=[[float(v) for v in row] for row in scaled],
        wavelength_rms_nm=wavelength_rms_from_covariance(scaled, pixel_range),
    )


def _report(
    exact: ExactMapping,
    family: Family,
    x: FloatArray,
    covariance: FloatArray,
    pixel_range: tuple[float, float],
    origin: str,
) -> tuple[QuadraticMapping, float]:
    """The quadratic report form with the coefficients' covariance, and the local RMS σ (nm)."""
    pixels = np.linspace(pixel_range[0], pixel_range[1], 256)
    fitted = QuadraticMapping.fit(pixels, exact.wavelength_nm(pixels))
    jacobian = family.jacobian(pixels, x)  # (n, P)
    design = np.stack([pixels**2, pixels, np.ones_like(pixels)], axis=1)
    projection = np.linalg.pinv(design)
    coefficient_covariance = projection @ jacobian @ covariance @ jacobian.T @ projection.T
    wavelength_variance = np.einsum("ij,jk,ik->i", jacobian, covariance, jacobian)
    local_rms = float(np.sqrt(np.mean(np.clip(wavelength_variance, 0.0, None))))
    method = f"{origin}+{'grating' if isinstance(family, GratingFamily) else 'profile'} fit"
    details: dict[str, Any] = {}
    if isinstance(exact, TiltedGrating):
        details["grating"] = exact.to_dict()
        details["quadratic_max_error_nm"] = float(
            np.max(np.abs(fitted.wavelength_nm(pixels) - exact.wavelength_nm(pixels)))
        )
    mapping = QuadraticMapping(
        fitted.a,
        fitted.b,
        fitted.c,
        method=method,
        pixel_range=pixel_range,
        covariance=tuple((float(r[0]), float(r[1]), float(r[2])) for r in coefficient_covariance),
        wavelength_rms_nm=wavelength_rms_from_covariance(coefficient_covariance, pixel_range),
        details=details,
        model=exact if isinstance(exact, TiltedGrating) else None,
    )
    return mapping, local_rms


@dataclass
class _FinalJudge:
    """Whether the final stage prefers a valley to the deciding stage's leader by the search's bar
    (tempered :data:`AMBIGUITY_DELTA_CHI2`, decision 0139's rule for a rival), the leader settled
    there once (``held``); ``evaluations``, the settles' count so far."""

    final: StageFit
    leader: Solution
    held: Solution | None = None
    evaluations: int = 0

    def prefers(self, x: FloatArray) -> Solution | None:
        """The valley at ``x`` settled on the final stage when that stage prefers it, else None."""
        settled = self.final.settle(x)
        self.evaluations += settled.evaluations
        if self.held is None:
            self.held = self.final.settle(self.leader.x)
            self.evaluations += self.held.evaluations
        return settled if _behind(self.held, settled) > AMBIGUITY_DELTA_CHI2 else None


def hidden_valleys(
    decided: Sequence[tuple[Any, Solution]],
    ranking: StageFit,
    deciding: StageFit,
    final: StageFit,
    pixel_range: tuple[float, float],
) -> tuple[list[tuple[Any, Solution]], int]:
    """The deciding stage's basins (``decided``, lowest first) with a valley the end grid stepped
    over found about the leader, and the evaluations made (decision 0145; the module docstring of
    :mod:`calib.wavelength.hidden_valleys`).

    ``ranking``, ``deciding`` and ``final`` are the search's
    :class:`StageFit` for the flexible response at the scan
    refinement's bins, on the deciding profile, and its final stage. Returns the basins as given
    when the leader's valley is wide enough for the grid, or when no valley found leads it by the
    search's bar on both the deciding and the final stage; else every basin, the new leader first
    (distinct, > 1 nm apart).
    """
    family, leader = decided[0]
    assert isinstance(family, QuadraticFamily)
    if valley_half_width_nm(leader, AMBIGUITY_DELTA_CHI2) >= 0.5 * LOCAL_SCAN[1]:
        return list(decided), 0
    points, shape = _quadratic_points(
        family.mapping(leader.x), family, (LOCAL_SCAN[0], REFINE_BIN_NM)
    )
    costs = ranking.costs(points)
    count = points.shape[0]
    # The grid is centred on the leader: its middle point is the leader's own cost on this view.
    own = float(costs[points.shape[0] // 2])
    # A valley as narrow as the leader's and deeper has a grid point at most half a step from its
    # bottom in each end, which costs at most (√a + √b)²·h² ≤ 4·max(a, b)·h² above that bottom
    # (a, b the ends' curvatures): a start that costs more than the leader's own point by that
    # reach cannot be in one (decision 0145, addendum).
    reach = 4.0 * max(end_curvatures(leader)) * (0.5 * REFINE_BIN_NM) ** 2
    probe = np.linspace(pixel_range[0], pixel_range[1], 9)
    seen: list[FloatArray] = [family.wavelengths(probe, leader.x)]
    starts: list[FloatArray] = []
    for index in _local_minima(costs, shape):
        point = points[index]
        placed = family.wavelengths(probe, point)
        # Outside the leader's valley and apart from the starts taken (> 1 nm somewhere).
        if any(np.max(np.abs(placed - other)) <= AMBIGUITY_MIN_DISTANCE_NM for other in seen):
            continue
        seen.append(placed)
        # The minima are lowest first: none after one beyond the reach is within it.
        if not costs[index] < own + reach:
            break
        starts.append(point)
        if len(starts) == EXTRA_DESCENTS:
            break
    found: list[tuple[Any, Solution]] = []
    judge = _FinalJudge(final, leader)
    for start in starts:
        outcome = deciding.descend(start)
        count += outcome.evaluations
        # Taken only where the search, had its scan held the valley, would have answered with it
        # unwarned: ahead by the broadband bar (below it two basins are an ambiguity, decision
        # 0104), on the deciding stage and on the final one (the finest view of the same
        # likelihood, the stiff response; decision 0139's rule for the coarse view's rival, whose
        # bar is the search's 25). On the validation split a valley 305 ahead on the deciding
        # stage and ahead on the final one was 10 nm off (Canon 5D, Kawakami, seed 2, no noise:
        # the search's answer, right and warned, would have become wrong and warned).
        if not (
            math.isfinite(outcome.cost)
            and _behind(leader, outcome) > BROADBAND_AMBIGUITY_DELTA_CHI2
        ):
            continue
        if judge.prefers(outcome.x) is not None:
            found.append((family, outcome))
    count += judge.evaluations
    if not found:
        return list(decided), count
    return _distinct([*found, *decided], pixel_range, MAX_BASINS + len(found)), count


#: At most this many rounds of :func:`end_probes` (a round that moves the leader starts another).
END_PROBE_ROUNDS = 2


def end_probes(
    decided: Sequence[tuple[Any, Solution]],
    ranking: StageFit,
    deciding: StageFit,
    final: StageFit,
    pixel_range: tuple[float, float],
) -> tuple[list[tuple[Any, Solution]], int]:
    """The deciding stage's basins (``decided``, lowest first) with a valley found by moving
    either end of the leader inwards to the deciding scan's reach and descending (decision 0152),
    and the evaluations made.

    With a broadband lamp alone and no 0th order, the deciding profile has minima a few nanometres
    apart at the ends of the profile, where the lamp's signal through the camera fades and holds
    an end only weakly; they are narrower than the end grids' step. On the validation split's
    paper scenes under lamps A and LED-B3 the search's answer put one end 6–13 nm too far out
    (the red end redder, or the blue end bluer), while the truth's valley inwards of it fitted the
    deciding profile by Δχ² 60–300 better and no grid point lay in it. Each end is moved inwards
    (towards the middle's wavelength) by :data:`LOCAL_SCAN`'s half-width, the edge of what the
    deciding scan reached (the middle following by half, as the grids move it), and sketched on
    ``ranking`` (the flexible response at the scan refinement's bins, where the deciding scan
    ranks its grid). The lowest sketch below the leader there, more than
    :data:`AMBIGUITY_MIN_DISTANCE_NM` from it, is descended on ``deciding``; that valley joins the
    basins, and leads them, when it is below the leader there and the final stage (``final``)
    prefers it by :data:`AMBIGUITY_DELTA_CHI2` (tempered; decision 0139's rule for a rival). The
    old leader stays a basin, so the search's σ and warning rules weigh the two. A round that
    moved the leader starts another from the new one, at most :data:`END_PROBE_ROUNDS`.
    """
    basins = list(decided)
    count = 0
    judge = _FinalJudge(final, basins[0][1])
    for _ in range(END_PROBE_ROUNDS):
        family, leader = basins[0]
        valley, evaluations = _probed_valley(family, leader, leader, ranking, deciding, pixel_range)
        count += evaluations
        if valley is None:
            break
        settled = judge.prefers(valley.x)
        if settled is None:
            basins = _kept_behind(basins, valley, pixel_range)
            break
        judge = _FinalJudge(final, valley, held=settled, evaluations=judge.evaluations)
        basins = _distinct([(family, valley), *basins], pixel_range, MAX_BASINS + 1)
    return basins, count + judge.evaluations


#: How far :func:`end_probes` moves an end inwards, as shares of :data:`LOCAL_SCAN`'s half-width:
#: the deciding scan's reach (decision 0152) and half of it, for a valley between the leader and
#: that reach (decision 0163: a predicted curve's red end 4 nm too far out, whose 6 nm move
#: sketched into another valley).
END_PROBE_SHARES = (1.0, 0.5)
#: Where every move by :data:`END_PROBE_SHARES` sketches uphill of the basin (on the ranking view),
#: each end is moved by this share as well: twice the scan's reach, as far as the line lamps'
#: red-end probe reaches (:data:`RED_END_PROBE_NM`). Decision 0169: a lamp A scene's blue end was
#: 27 nm too blue, its 3 and 6 nm moves sketched uphill and its 12 nm move into the truth's valley;
#: taken with the nearer moves, the 12 nm move sketched lower than their right valley into a wrong
#: one in two other scenes.
END_PROBE_FAR_SHARES = (2.0,)


def _inward_starts(basin: Solution, shares: Sequence[float] = END_PROBE_SHARES) -> list[FloatArray]:
    """:func:`end_probes`' moves of ``basin``: each end inwards by ``shares`` of
    :data:`LOCAL_SCAN`'s half-width, the middle by half (the parameters are the wavelengths at
    the profile's first pixel, middle and last)."""
    starts = []
    for share in shares:
        for end in (0, 2):
            shift = share * LOCAL_SCAN[0] * float(np.sign(basin.x[1] - basin.x[end]))
            start = basin.x.copy()
            start[end] += shift
            start[1] += 0.5 * shift
            starts.append(start)
    return starts


def _probed_valley(
    family: Any,
    basin: Solution,
    leader: Solution,
    ranking: StageFit,
    deciding: StageFit,
    pixel_range: tuple[float, float],
    starts: Sequence[FloatArray] | None = None,
) -> tuple[Solution | None, int]:
    """One round of the probes about ``basin`` (:func:`end_probes`, :func:`stalled_probe`,
    :func:`whole_shift_probe`): ``starts`` (default: each end moved inwards,
    :func:`_inward_starts`, and further, :data:`END_PROBE_FAR_SHARES`, when the nearer moves
    found no valley) sketched on ``ranking``, the lowest sketch below ``basin`` there (and more
    than :data:`AMBIGUITY_MIN_DISTANCE_NM` from it) descended on ``deciding``; that valley when it
    is below ``leader`` there and apart from ``basin``, else the next group's (``None`` when none
    is); and the evaluations made. (Descending the two lowest sketches and taking the valley the
    deciding stage puts lower, decision 0171, moved one validation mapping by 0.08 nm and fixed
    none: decision 0172.)"""
    assert isinstance(family, QuadraticFamily)
    probe = np.linspace(pixel_range[0], pixel_range[1], 9)
    placed = family.wavelengths(probe, basin.x)
    count = 0
    groups = (
        [_inward_starts(basin), _inward_starts(basin, END_PROBE_FAR_SHARES)]
        if starts is None
        else [list(starts)]
    )
    # The basin's own cost on the ranking view, each point at its own prior scale (as descents
    # compare): costed once, with the first group's sketches.
    basin_cost: float | None = None
    for group in groups:
        sketches = []
        # The sketches run their whole round: stopping those whose own model ends hopelessly
        # behind the basin's own point moved four predicted-curve mappings, two of them right to
        # 6–7 nm off (decision 0165, addendum).
        for start in group:
            sketches.append(ranking.sketch(start))
            count += sketches[-1].evaluations
        points = [sketch.x for sketch in sketches]
        costs = ranking.costs(np.stack(points if basin_cost is not None else [basin.x, *points]))
        count += costs.size
        if basin_cost is None:
            basin_cost, costs = float(costs[0]), costs[1:]
        lower = [
            (float(cost), x)
            for cost, x in zip(costs, points, strict=True)
            if cost < basin_cost
            and np.max(np.abs(family.wavelengths(probe, x) - placed)) > AMBIGUITY_MIN_DISTANCE_NM
        ]
        valley = deciding.descend(min(lower, key=lambda item: item[0])[1]) if lower else None
        if valley is not None:
            count += valley.evaluations
        if (
            valley is not None
            and valley.cost < leader.cost
            and np.max(np.abs(family.wavelengths(probe, valley.x) - placed))
            > AMBIGUITY_MIN_DISTANCE_NM
        ):
            return valley, count
    return None, count


#: The spacing (nm) of the whole-mapping aliases of a broadband profile: the deciding and the
#: scan's response nodes (:data:`COARSE_NODES_NM`); on the validation split's lamp A scenes the
#: wrong answers shifted as a whole were 9–12 nm off (decision 0158).
WHOLE_SHIFT_NM = COARSE_NODES_NM


def _led_by(
    decided: Sequence[tuple[Any, Solution]],
    valley: Solution | None,
    final: StageFit,
    pixel_range: tuple[float, float],
    count: int,
) -> tuple[list[tuple[Any, Solution]], int]:
    """``decided`` with ``valley`` leading when the final stage prefers it to the leader by
    :data:`AMBIGUITY_DELTA_CHI2` (the old leader stays a basin), and ``count`` with the final
    stage's evaluations."""
    if valley is None:
        return list(decided), count
    family, leader = decided[0]
    judge = _FinalJudge(final, leader)
    settled = judge.prefers(valley.x)
    count += judge.evaluations
    if settled is None:
        return _kept_behind(decided, valley, pixel_range), count
    return _distinct([(family, valley), *decided], pixel_range, MAX_BASINS + 1), count


def _kept_behind(
    decided: Sequence[tuple[Any, Solution]], valley: Solution, pixel_range: tuple[float, float]
) -> list[tuple[Any, Solution]]:
    """``decided`` with a probe's ``valley`` kept as a basin behind the leader: it is below the
    leader on the deciding stage but the final stage does not prefer it by the bar, so the leader
    stays the answer and the two stages' disagreement is weighed by the search's σ and warning
    rules instead of being dropped (decision 0168: a predicted curve's right valley, preferred by
    the final stage by 12 below the bar of 25, was dropped and the wrong leader answered 4.6 nm
    off, unwarned)."""
    family, _ = decided[0]
    return _distinct(
        [decided[0], (family, valley), *decided[1:]], pixel_range, MAX_BASINS + 1, decided[0]
    )


def whole_shift_probe(
    decided: Sequence[tuple[Any, Solution]],
    ranking: StageFit,
    deciding: StageFit,
    final: StageFit,
    pixel_range: tuple[float, float],
) -> tuple[list[tuple[Any, Solution]], int]:
    """The deciding stage's basins (``decided``, lowest first) with a valley found by shifting
    the whole leader by ± :data:`WHOLE_SHIFT_NM` (decision 0158), and the evaluations made: the
    two shifted mappings sketched and descended as :func:`end_probes` does its moves, the valley
    leading under the same rules (below the leader on the deciding stage, preferred by the final
    stage by :data:`AMBIGUITY_DELTA_CHI2`); the old leader stays a basin."""
    family, leader = decided[0]
    starts = [leader.x + shift for shift in (-WHOLE_SHIFT_NM, WHOLE_SHIFT_NM)]
    valley, count = _probed_valley(
        family, leader, leader, ranking, deciding, pixel_range, starts=starts
    )
    return _led_by(decided, valley, final, pixel_range, count)


def stalled_probe(
    decided: Sequence[tuple[Any, Solution]],
    scan_best: Solution,
    ranking: StageFit,
    deciding: StageFit,
    final: StageFit,
    pixel_range: tuple[float, float],
) -> tuple[list[tuple[Any, Solution]], int]:
    """The deciding stage's basins (``decided``, lowest first) with a valley found about the
    scan's best basin when its deciding descent (``scan_best``) stalled hopelessly behind the
    leader (decision 0158), and the evaluations made.

    :func:`end_probes` moves the leader's ends only. On the validation split (lamp A, seed 4,
    Canon 10D (Kawakami), no noise) the scan's best basin was the truth's with its blue end 10 nm
    too blue, and its deciding descent stopped in a narrow valley of its own at Δχ² ~92 000
    behind the leader (an alias 10 nm off in the middle); its blue end moved inwards by 6 nm
    descended to the truth. A scan's best basin that ends more than
    :data:`HOPELESS_DELTA_CHI2` behind the deciding leader is probed as :func:`end_probes` probes
    the leader (one round), and the valley found leads when it is below the leader on the
    deciding stage and the final stage prefers it by :data:`AMBIGUITY_DELTA_CHI2`; the old
    leader stays a basin.
    """
    family, leader = decided[0]
    if _behind(scan_best, leader) <= HOPELESS_DELTA_CHI2:
        return list(decided), 0
    valley, count = _probed_valley(family, scan_best, leader, ranking, deciding, pixel_range)
    return _led_by(decided, valley, final, pixel_range, count)


#: How far (in its own curvature σ) :func:`end_profile` moves each end of a broadband-only mapping
#: to read the likelihood's rise there: where an error the stated σ should cover would lie (the
#: benches' 3σ bar and beyond). Within one σ the valley is the parabola the curvature states (a
#: median rise of 0.7–0.9 on the validation LED-BH1 scenes); it flattens further out (at four σ a
#: median 2.5–10, not 16). Decision 0155.
END_PROFILE_STEP = 4.0
#: An end whose move by :data:`END_PROFILE_STEP` of its σ raises the (Birge-scaled) cost by less
#: than this — one σ's Δχ² — is not held by the likelihood: the result warns. Chosen on the
#: validation split only (decision 0155: on LED-BH1 seeds 0/1, 0 leaves one more of the 12 silent
#: mappings silent and warns 7 fewer of the 352 mappings that are right).
END_PROFILE_WARN_DELTA_CHI2 = 1.0


@dataclass(frozen=True)
class EndProfile:
    """The final stage's likelihood along one end of the mapping (decision 0155).

    Attributes
    ----------
    index
        The family's parameter (the end's wavelength) moved.
    sigma_nm
        Its curvature σ (nm).
    delta_chi2
        The smaller rise of the cost (Birge-scaled) at ±:data:`END_PROFILE_STEP` σ.
    factor
        How much wider the end's σ is than its curvature's: the step over √Δχ² (a Gaussian
        valley's ratio), at least 1, at most the step (an end the likelihood does not hold
        within the step is stated at the step).
    """

    index: int
    sigma_nm: float
    delta_chi2: float
    factor: float

    def to_dict(self) -> dict[str, float]:
        return {"sigma_nm": self.sigma_nm, "delta_chi2": self.delta_chi2, "factor": self.factor}


def end_profile(
    fit: StageFit, x: FloatArray, covariance: FloatArray, scale: float
) -> tuple[FloatArray, tuple[EndProfile, ...]]:
    """The covariance of a broadband-only quadratic mapping's parameters ``x`` widened along each
    end to what the final stage's own likelihood states there, and what was read (decision 0155).

    The curvature (Gauss–Newton) covariance states the valley as a parabola. With a broadband lamp
    alone the mapping's ends are held only where the lamp's signal through the camera fades (a
    white LED's narrow blue pump leaves little below 440 nm), and there the cost rises more
    slowly than the parabola: on the validation LED-BH1 scenes (1 % and 3 % noise) a move of an
    end by four of its σ raised it by a median Δχ² of 2.5–6, not 16, and for two blue ends 4.4 nm
    off by nothing at all.
    Each end is moved by ±:data:`END_PROFILE_STEP` of its σ, the other parameters along their
    regression on it (the covariance's own direction); the cost (every nuisance re-solved, in
    units of ``scale``, the fit's Birge factor) at the flatter side gives the end's σ as a
    Gaussian valley of that rise would, and the covariance gains the difference along that
    direction (only those two directions widen).
    """
    widened = np.array(covariance, dtype=np.float64)
    ends = [
        (index, math.sqrt(float(covariance[index, index])))
        for index in (0, len(x) - 1)
        if scale > 0 and float(covariance[index, index]) > 0
    ]
    if not ends:
        return widened, ()
    directions = [np.asarray(covariance[:, index], dtype=np.float64) / sd for index, sd in ends]
    # The point and both moves of each end in one batch (the point costed once).
    moves = [
        x + sign * END_PROFILE_STEP * direction for direction in directions for sign in (-1, 1)
    ]
    costs = fit.costs(np.array([x, *moves]))
    read: list[EndProfile] = []
    for k, ((index, sd), direction) in enumerate(zip(ends, directions, strict=True)):
        rise = float(min(costs[1 + 2 * k], costs[2 + 2 * k]) - costs[0]) / scale
        factor = END_PROFILE_STEP / math.sqrt(max(rise, 1.0)) if math.isfinite(rise) else 1.0
        factor = max(factor, 1.0)
        widened += (factor**2 - 1.0) * np.outer(direction, direction)
        read.append(EndProfile(index, sd, rise, factor))
    return widened, tuple(read)
