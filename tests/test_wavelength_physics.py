"""The mapping's physics: the grating equation through a lens, its families' analytic derivatives, the
banded response model's exact Jacobian, the rig's prior and a grating file's stored geometry."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from calib.core.datasets import colour_science_cameras, find_camera
from calib.core.errors import InputError
from calib.core.grating_file import (
    GRATING_FORMAT_VERSION,
    GratingEfficiency,
    GratingFileError,
    read_grating_file,
    write_grating_file,
)
from calib.core.lamp_specs import colour_lamp
from calib.core.mapping import GratingGeometry, QuadraticMapping, TiltedGrating
from calib.core.observations import LampObservation
from calib.core.spectra import DEFAULT_GRID, Spectrum
from calib.model.bases import fallback_camera_basis
from calib.model.forward import blur_kernel, pixel_edges, render_observation
from calib.wavelength.families import GratingFamily, QuadraticFamily, grating_prior
from calib.wavelength.least_squares import levenberg_marquardt
from calib.wavelength.locate import locate_mapping
from calib.wavelength.response_model import (
    RIDGE,
    SHARED_EDGES_FROM,
    ResponseModel,
    hat_averages,
)
from calib.wavelength.rig_prior import (
    RigGeometry,
    RigOptics,
    optics_from_observation,
    rig_prior,
    same_setup,
)


def _central_difference(function, x: np.ndarray, step: float) -> np.ndarray:
    columns = []
    for k in range(x.size):
        delta = np.zeros_like(x)
        delta[k] = step
        columns.append((function(x + delta) - function(x - delta)) / (2 * step))
    return np.stack(columns, axis=-1)


# ------------------------------------------------------------------------------ the grating


def test_tilted_grating_round_trips_and_reduces_to_the_parts_geometry():
    grating = TiltedGrating(
        0.3, 5000.0, 4.0, zero_order_px=-120.0, orientation=1, axis_offset_px=300.0
    )
    pixels = np.linspace(1200.0, 2600.0, 9)
    np.testing.assert_allclose(grating.pixel_at(grating.wavelength_nm(pixels)), pixels, atol=1e-8)
    slope = np.gradient(grating.wavelength_nm(pixels), pixels)
    np.testing.assert_allclose(grating.dispersion_at(pixels)[1:-1], slope[1:-1], rtol=2e-3)
    assert TiltedGrating.from_dict(json.loads(json.dumps(grating.to_dict()))) == grating
    # Normal incidence, 0th order on the axis: the rig's parts (GratingGeometry) exactly.
    parts = GratingGeometry(grooves_per_mm=600.0, focal_length_mm=24.0, pixel_pitch_um=4.0)
    tilted = TiltedGrating(1e6 / 600.0 / parts.focal_length_px, parts.focal_length_px)
    np.testing.assert_allclose(tilted.wavelength_nm(pixels), parts.wavelength_nm(pixels), atol=1e-9)


def test_the_other_first_order_is_the_same_grating_seen_the_other_way():
    grating = TiltedGrating(0.25, 6000.0, 6.0, axis_offset_px=400.0)
    other = grating.other_order()
    spacing = grating.groove_spacing_nm
    u = np.array([1500.0, 2500.0])
    # −1 order: sin θ − sin θ' = λ/d, measured away from the spot on the other side.
    theta = math.radians(6.0)
    angle = np.arctan((-u + 400.0) / 6000.0) - math.atan(400.0 / 6000.0)
    expected = spacing * (math.sin(theta) - np.sin(theta + angle))
    np.testing.assert_allclose(other.wavelength_nm(u), expected, rtol=1e-12)


def test_a_mirrored_grating_mapping_falls_with_the_pixel():
    rising = TiltedGrating(0.3, 5000.0, 2.0, zero_order_px=-1500.0)
    falling = replace(rising, zero_order_px=1500.0 + 2000.0, orientation=-1)
    pixels = np.linspace(0.0, 2000.0, 5)
    np.testing.assert_allclose(falling.wavelength_nm(pixels), rising.wavelength_nm(2000.0 - pixels))
    assert np.all(falling.dispersion_at(pixels) < 0)


def test_tilted_grating_refuses_a_bad_orientation():
    with pytest.raises(InputError, match="orientation"):
        TiltedGrating(0.3, 5000.0, orientation=0)


# ----------------------------------------------------------------------- analytic derivatives


@pytest.mark.parametrize("orientation", [1, -1])
def test_grating_family_jacobian_equals_finite_differences(orientation):
    family = GratingFamily(
        grating_prior(zero_order_px=None, grooves_per_mm=None), orientation, axis_offset_px=350.0
    )
    x = np.array([-1800.0 * orientation, math.log(1600.0), math.log(7000.0), 6.0])
    pixels = np.linspace(0.0, 2500.0, 11)
    numeric = _central_difference(lambda v: family.wavelengths(pixels, v), x, 1e-6)
    np.testing.assert_allclose(family.jacobian(pixels, x), numeric, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("orientation", [1, -1])
def test_grating_family_one_pass_evaluation_is_wavelengths_jacobian_and_validity(orientation):
    """:meth:`GratingFamily.evaluate` (a fit's inner loop) against the three separate calls and
    against finite differences, with a held parameter, a soft prior and a point outside."""
    family = GratingFamily(
        grating_prior(zero_order_px=None, grooves_per_mm=600.0, focal_length_px=7000.0),
        orientation,
        axis_offset_px=350.0,
    )
    spacing = math.log(1e6 / 600.0)
    # The 0th order 1800 px before the profile's first wavelength (at 0 or at 2500 px).
    zero_order = -1800.0 if orientation > 0 else 4300.0
    x = np.array([zero_order, spacing + 0.01, math.log(7000.0), 6.0])
    pixels = np.linspace(0.0, 2500.0, 11)
    span = (0.0, 2500.0)
    evaluated = family.evaluate(pixels, x, span)
    assert evaluated is not None and evaluated[1] is not None
    np.testing.assert_allclose(evaluated[0], family.wavelengths(pixels, x), rtol=1e-13)
    np.testing.assert_allclose(evaluated[1], family.jacobian(pixels, x), rtol=1e-12, atol=1e-12)
    numeric = _central_difference(lambda v: family.wavelengths(pixels, v), x, 1e-6)
    np.testing.assert_allclose(evaluated[1], numeric, rtol=1e-6, atol=1e-6)
    assert family.evaluate(pixels, x, span, with_jacobian=False)[1] is None  # type: ignore[index]
    # The 0th order inside the profile: not a valid mapping, as valid() says.
    inside = np.array([1200.0, spacing, math.log(7000.0), 6.0])
    assert not family.valid(inside, span)[0]
    assert family.evaluate(pixels, inside, span) is None
    assert family.evaluate(pixels, np.array([np.nan, spacing, 8.0, 0.0]), span) is None
    # The prior rows and their Jacobian: ((x − mean)/σ, 1/σ) for the soft parameters only.
    rows, row_jacobian = family.prior_rows(x)
    np.testing.assert_allclose(rows, [0.5, 0.0, 1.2], atol=1e-12)
    np.testing.assert_allclose(
        row_jacobian, [[0.0, 50.0, 0.0, 0.0], [0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.0, 0.2]]
    )


def test_quadratic_family_is_linear_in_the_end_wavelengths():
    family = QuadraticFamily((0.0, 800.0))
    truth = QuadraticMapping(-2e-5, 0.43, 383.0)
    x = family.parameters(truth)
    pixels = np.linspace(0.0, 800.0, 7)
    np.testing.assert_allclose(family.mapping(x).wavelength_nm(pixels), truth.wavelength_nm(pixels))
    numeric = _central_difference(lambda v: family.wavelengths(pixels, v), x, 1e-3)
    np.testing.assert_allclose(family.jacobian(pixels), numeric, atol=1e-9)


@pytest.fixture(scope="module")
def fluorescent_profile() -> LampObservation:
    camera = find_camera(colour_science_cameras(), "Canon EOS 5D Mark II").sensitivity
    truth = QuadraticMapping(-2.2e-5, 0.43, 383.0, pixel_range=(0.0, 799.0))
    return render_observation(
        colour_lamp("FL2"), camera, mapping=truth, pixel=800, slit_width_px=3.0, psf_sigma_px=1.0
    ).observation


def _blurred_fluorescent_model(profile):
    """FL2's profile through a 3 px slit and 1 px blur: its response model, the quadratic family,
    the pixel edges and a mapping off the truth by (0.8, −0.4, 0.6) in the family's parameters."""
    prior = fallback_camera_basis(exclude=["Canon EOS 5D Mark II"]).prior()
    model = ResponseModel.build(
        profile,
        DEFAULT_GRID,
        node_step_nm=10.0,
        prior=prior,
        flexibility=0.05,
        kernel=blur_kernel(3.0, 1.0),
    )
    family = QuadraticFamily((0.0, 799.0))
    x = family.parameters(QuadraticMapping(-2.2e-5, 0.43, 383.0)) + np.array([0.8, -0.4, 0.6])
    return model, family, pixel_edges(profile.pixel), x


def test_response_model_jacobian_equals_finite_differences(fluorescent_profile):
    """The exact variable-projection Jacobian (Golub & Pereyra) of the residual in the mapping."""
    model, family, edges, x = _blurred_fluorescent_model(fluorescent_profile)
    fixed = model.reference(family.wavelengths(edges, x))
    residual, jacobian, _ = fixed.residual(family.wavelengths(edges, x), family.jacobian(edges))
    assert jacobian is not None
    numeric = _central_difference(
        lambda v: fixed.residual(family.wavelengths(edges, v))[0], x, 1e-4
    )
    np.testing.assert_allclose(jacobian, numeric, rtol=1e-5, atol=1e-6 * np.abs(numeric).max())
    # The batched cost is the residual's squared norm (computed as ‖Wy‖² − bᵀr̂: a difference of
    # large numbers on noise-free data, hence the tolerance).
    cost = fixed.costs(family.wavelengths(edges, x)[None], adaptive=False)
    np.testing.assert_allclose(cost, [residual @ residual], rtol=1e-5)


def test_the_fit_reads_its_reference_and_the_family_keeps_its_jacobian(fluorescent_profile):
    """Decision 0061's shortcuts give the same numbers: the first residual at the reference
    mapping reuses the band and normal matrices :meth:`ResponseModel.reference` built (any other
    mapping builds its own), and the quadratic family's Jacobian is kept per pixel array
    (read-only, the same values, a bounded number kept)."""
    model, family, edges, x = _blurred_fluorescent_model(fluorescent_profile)
    at = family.wavelengths(edges, x)
    fixed = model.reference(at)
    assert fixed.referenced is not None
    plain = replace(fixed, referenced=None)
    for where in (at, family.wavelengths(edges, x + np.array([0.1, 0.0, -0.1]))):
        kept = fixed.residual(where, family.jacobian(edges))
        fresh = plain.residual(where, family.jacobian(edges))
        assert np.array_equal(kept[0], fresh[0]) and kept[1] is not None and fresh[1] is not None
        assert np.array_equal(kept[1], fresh[1])
    jacobian = family.jacobian(edges)
    assert family.jacobian(edges.copy()) is jacobian and not jacobian.flags.writeable
    design = np.stack([edges**2, edges, np.ones_like(edges)], axis=1)
    np.testing.assert_array_equal(jacobian, design @ family._to_coefficients)
    for count in range(20):
        family.jacobian(np.linspace(0.0, 10.0 + count, 7))
    assert len(family._jacobians) <= 8


def test_response_model_band_derivative_and_normal_matrix(fluorescent_profile):
    """The banded matrix' derivative against finite differences of its values, and the normal
    matrix assembled from its diagonals against the dense ``AᵀW²A``, for a batch."""
    model, family, edges_px, x = _blurred_fluorescent_model(fluorescent_profile)
    edges = family.wavelengths(edges_px, x)[None]
    band = model.band(edges, family.jacobian(edges_px)[None])
    assert band.derivative is not None
    # Each edge's cumulatives computed once for the pixels sharing it (a blurred profile) and
    # filtered tap by tap are the pixel-by-pixel ones (the same sums up to rounding).
    assert model.filter.size > SHARED_EDGES_FROM
    windows, _ = model._windows(edges)
    columns = np.minimum(band.columns, model.n_nodes - 1)
    direct, _ = model.columns.evaluate(windows[..., None, :], columns[..., None])
    expected = np.einsum("knwl,l->knw", direct, model.filter) * (band.columns < model.n_nodes)
    np.testing.assert_allclose(band.values, expected, rtol=0, atol=1e-13 * np.abs(expected).max())
    step = 1e-4
    for k in range(x.size):
        delta = np.zeros(3)
        delta[k] = step
        up = model.band(family.wavelengths(edges_px, x + delta)[None])
        down = model.band(family.wavelengths(edges_px, x - delta)[None])
        assert np.array_equal(up.first, band.first) and np.array_equal(down.first, band.first)
        numeric = (up.values - down.values) / (2 * step)
        np.testing.assert_allclose(
            band.derivative[..., k], numeric, rtol=1e-5, atol=1e-6 * np.abs(numeric).max()
        )
    # A batch of two mappings (one falling): each normal matrix is the dense one.
    falling = family.wavelengths(edges_px, x[::-1])
    batch = model.band(np.stack([edges[0], falling]))
    diagonals, rhs = model._normal(batch)
    size = model.n_nodes
    width = batch.values.shape[-1]
    assert diagonals.shape == (2, 3, size, width)
    normal = np.zeros((2, 3, size, size))
    for offset in range(width):
        rows = np.arange(size - offset)
        normal[..., rows, rows + offset] = diagonals[:, :, : size - offset, offset]
        normal[..., rows + offset, rows] = diagonals[:, :, : size - offset, offset]
        # Nothing is kept past the matrix.
        assert not np.any(diagonals[:, :, size - offset :, offset])
    for k in range(2):
        dense = np.zeros((edges_px.size - 1, size))
        rows = np.arange(edges_px.size - 1)[:, None]
        np.add.at(dense, (rows, batch.columns[k]), batch.values[k])
        for c in range(3):
            weighted = dense * model.weights[:, c, None] ** 2
            np.testing.assert_allclose(normal[k, c], dense.T @ weighted, rtol=1e-12, atol=1e-300)
            np.testing.assert_allclose(
                rhs[k, c], weighted.T @ fluorescent_profile.profile[:, c], rtol=1e-12
            )


def test_response_model_systems_are_the_dense_sum_to_the_last_bit(fluorescent_profile):
    """The per-channel systems written diagonal by diagonal from the normal matrices' diagonals
    are ``(AᵀW²A + w_Δ ΔᵀΔ) + β̂⁻² FᵀF`` plus the ridge, summed densely in that order (the same
    numbers, not merely close), and the penalty weight is the dense normal matrix' trace's."""
    model, family, edges_px, x = _blurred_fluorescent_model(fluorescent_profile)
    assert np.any(model.penalty)  # margins, so the penalty's diagonals are written too
    falling = family.wavelengths(edges_px, x[::-1])
    band = model.band(np.stack([family.wavelengths(edges_px, x), falling]))
    diagonals, _ = model._normal(band)
    size, width = model.n_nodes, band.values.shape[-1]
    normal = np.zeros((2, 3, size, size))
    for offset in range(width):
        rows = np.arange(size - offset)
        normal[..., rows, rows + offset] = diagonals[:, :, : size - offset, offset]
        normal[..., rows + offset, rows] = diagonals[:, :, : size - offset, offset]
    weight = model._penalty_weight(diagonals)
    np.testing.assert_array_equal(weight, model.smoothness * (np.einsum("kcii->kc", normal) / size))
    scale = np.array([0.7, 1.9])
    systems, _, _ = model._systems(diagonals, scale, weight)
    expected = normal + weight[..., None, None] * model.penalty
    expected += (1.0 / scale**2)[:, None, None, None] * model.precision
    ridge = RIDGE * np.einsum("kcii->kc", expected) / size
    expected[..., np.arange(size), np.arange(size)] += ridge[..., None]
    np.testing.assert_array_equal(systems, expected)


def test_the_deferred_jacobian_is_the_eager_one_and_computed_only_for_accepted_points(
    fluorescent_profile,
):
    prior = fallback_camera_basis(exclude=["Canon EOS 5D Mark II"]).prior()
    model = ResponseModel.build(
        fluorescent_profile, DEFAULT_GRID, node_step_nm=10.0, prior=prior, flexibility=0.05
    )
    family = QuadraticFamily((0.0, 799.0))
    edges_px = pixel_edges(fluorescent_profile.pixel)
    x = family.parameters(QuadraticMapping(-2.2e-5, 0.43, 383.0)) + np.array([0.8, -0.4, 0.6])
    fixed = model.reference(family.wavelengths(edges_px, x))
    eager = fixed.residual(family.wavelengths(edges_px, x), family.jacobian(edges_px))
    lazy = fixed.residual_lazy(family.wavelengths(edges_px, x), family.jacobian(edges_px))
    assert eager[1] is not None and lazy[1] is not None
    np.testing.assert_array_equal(lazy[0], eager[0])
    np.testing.assert_array_equal(lazy[1](), eager[1])

    # The fit asks for the Jacobian of the points it accepts only (and of its start).
    computed, accepted = [], []

    def function(v, with_jacobian):
        residual, jacobian, _ = fixed.residual_lazy(
            family.wavelengths(edges_px, v), family.jacobian(edges_px)
        )
        cost = float(residual @ residual)

        def deferred():
            computed.append(cost)
            assert jacobian is not None
            return jacobian()

        return residual, deferred

    def watched(v, with_jacobian):
        outcome = function(v, with_jacobian)
        accepted.append(float(outcome[0] @ outcome[0]))
        return outcome

    solution = levenberg_marquardt(watched, x, max_iterations=8, tolerance=1e-9)
    assert 1 < len(computed) < solution.evaluations  # some trials were rejected
    # The stopping point's Jacobian is computed when the solution's reader asks for it (decision
    # 0153), once.
    before = len(computed)
    assert solution.jacobian is solution.jacobian
    assert before <= len(computed) <= before + 1
    # Every computed Jacobian belongs to a point that lowered the cost (or the start).
    lowest = accepted[0]
    for cost in computed[1:]:
        assert cost < lowest
        lowest = cost
    assert solution.cost == pytest.approx(lowest)


def test_hat_averages_are_the_integrating_resample():
    axis = np.linspace(380.0, 780.0, 4001)
    spectrum = Spectrum(axis, 1.0 + np.sin(axis / 0.7) ** 2)
    from calib.core.spectra import WavelengthGrid

    grid = WavelengthGrid(400.0, 700.0, 1.0)
    np.testing.assert_allclose(
        hat_averages(spectrum, 400.0, 1.0, grid.size),
        spectrum.resample(grid, "integrate").values,
        rtol=1e-9,
    )


def test_levenberg_marquardt_with_a_rejected_region():
    def function(x, with_jacobian):
        if x[0] <= 0:
            return None  # outside the valid region
        t = np.linspace(0.0, 1.0, 20)
        residual = x[0] * np.exp(-x[1] * t) - 2.0 * np.exp(-3.0 * t)
        jacobian = np.stack([np.exp(-x[1] * t), -x[0] * t * np.exp(-x[1] * t)], axis=1)
        return residual, jacobian if with_jacobian else None

    solution = levenberg_marquardt(function, np.array([0.5, 1.0]))
    np.testing.assert_allclose(solution.x, [2.0, 3.0], atol=1e-6)


def test_levenberg_marquardt_geodesic_follows_a_curved_valley():
    # A narrow Rosenbrock valley as residuals (1000 (y − x²), 1 − x): the plain loop crawls
    # along the parabola, the bent steps follow it; both end at (1, 1).
    def function(x, with_jacobian):
        residual = np.array([1000.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])
        jacobian = np.array([[-2000.0 * x[0], 1000.0], [-1.0, 0.0]])
        return residual, jacobian if with_jacobian else None

    start = np.array([-1.2, 1.0])
    plain = levenberg_marquardt(function, start, max_iterations=1000, tolerance=1e-14)
    bent = levenberg_marquardt(function, start, max_iterations=1000, tolerance=1e-14, geodesic=True)
    np.testing.assert_allclose(plain.x, [1.0, 1.0], atol=1e-5)
    np.testing.assert_allclose(bent.x, [1.0, 1.0], atol=1e-5)
    assert bent.evaluations < 0.6 * plain.evaluations


def test_levenberg_marquardt_stops_when_no_residual_moves():
    def function(x, with_jacobian):
        t = np.linspace(0.0, 1.0, 20)
        residual = x[0] * np.exp(-x[1] * t) - 2.0 * np.exp(-3.0 * t)
        jacobian = np.stack([np.exp(-x[1] * t), -x[0] * t * np.exp(-x[1] * t)], axis=1)
        return residual, jacobian if with_jacobian else None

    start = np.array([0.5, 1.0])
    full = levenberg_marquardt(function, start, max_iterations=200, tolerance=0.0)
    early = levenberg_marquardt(
        function, start, max_iterations=200, tolerance=0.0, step_tolerance=1e-3
    )
    assert early.evaluations < full.evaluations
    np.testing.assert_allclose(early.x, full.x, atol=1e-3)


# ------------------------------------------------------------------------------- the rig


def _spot_observation(metadata: dict[str, object]) -> LampObservation:
    pixel = np.arange(1000.0, 1400.0)
    return LampObservation(
        "LED",
        colour_lamp("LED-B3"),
        pixel,
        np.ones((pixel.size, 3)),
        metadata=metadata,
        pixel_origin="direct_spot",
    )


GEOMETRY = {
    "sensor_shape_px": [4000, 6000],
    "spot_centre_px": [1800.0, 2100.0],
    "orders": [{"side": 1, "angle_deg": 0.0, "start_px": 900.0, "stop_px": 2600.0}],
}


def test_optics_come_from_exif_and_the_spot_geometry():
    observation = _spot_observation(
        {
            "optics": {"camera": "Nikon D7000", "focal_length_mm": 35.0},
            "geometry": GEOMETRY,
        }
    )
    optics = optics_from_observation(observation)
    assert optics.pitch_source == "sensor table"  # the D7000 writes no focal plane resolution
    assert optics.pixel_pitch_um == pytest.approx(23.6e3 / 4928)
    assert optics.focal_length_px == pytest.approx(35.0 / (23.6e3 / 4928 * 1e-3))
    # The spot is 1200 px left of the sensor's centre along the order (angle 0: +x).
    assert optics.axis_offset_px == pytest.approx(1800.0 - 3000.0)
    prior, why = rig_prior(optics, grooves_per_mm=600.0)
    assert prior is not None and "600 lines/mm" in why and "35 mm" in why
    assert prior.fixed() == {"zero_order_px": 0.0}
    assert prior.values["log_spacing"][0] == pytest.approx(math.log(1e6 / 600.0))
    assert prior.axis_offset_px == pytest.approx(-1200.0)
    # The rig's configured line density travels in the same record.
    configured = optics_from_observation(
        _spot_observation({"optics": {"focal_length_mm": 35.0, "grooves_per_mm": 500.0}})
    )
    assert configured.grooves_per_mm == 500.0
    prior, why = rig_prior(configured)
    assert prior is not None and "500 lines/mm" in why
    assert prior.values["log_spacing"][0] == pytest.approx(math.log(1e6 / 500.0))


def test_a_stored_geometry_is_reused_whole_only_in_the_same_setup():
    grating = TiltedGrating(0.3, 7300.0, 3.5, axis_offset_px=-1200.0)
    stored_optics = RigOptics(
        camera="NIKON D7000",
        focal_length_mm=35.0,
        pixel_pitch_um=4.79,
        order_angle_deg=0.0,
        band_distance_px=1750.0,
    )
    stored = RigGeometry(grating, stored_optics, 600.0)
    same = replace(stored_optics, band_distance_px=1760.0, order_angle_deg=0.3)
    assert same_setup(stored_optics, same)[0]
    prior, why = rig_prior(same, stored=stored)
    assert prior is not None and "from the grating file" in why
    assert prior.values["log_focal"][0] == pytest.approx(math.log(7300.0))
    assert prior.values["log_focal"][1] == 0.01
    assert prior.values["incidence_deg"][0] == pytest.approx(3.5)
    assert prior.values["incidence_deg"][1] == 1.0
    # Another lens: the sheet's spacing holds, the geometry is refitted (EXIF's focal length).
    zoomed = replace(same, focal_length_mm=50.0)
    ok, reason = same_setup(stored_optics, zoomed)
    assert not ok and "focal length" in reason
    prior, why = rig_prior(zoomed, stored=stored)
    assert prior is not None and "refitted" in why
    assert prior.values["log_spacing"][0] == pytest.approx(math.log(grating.groove_spacing_nm))
    assert prior.values["log_focal"][1] == 0.05
    # A turned camera: the order's angle moved.
    assert not same_setup(stored_optics, replace(same, order_angle_deg=4.0))[0]
    # Another body behind the same lens and grating: the angles hold, the focal length in pixels
    # follows the pitch, both a little looser than for the same setup.
    body = replace(same, camera="NIKON D5300", pixel_pitch_um=3.92)
    prior, why = rig_prior(body, stored=stored)
    assert prior is not None and "the same lens" in why
    assert prior.values["log_focal"][0] == pytest.approx(math.log(7300.0 * 4.79 / 3.92))
    assert prior.values["incidence_deg"][0] == pytest.approx(3.5)
    assert prior.values["incidence_deg"][1] == 2.0


def test_a_reused_geometry_keeps_its_axis_offset_with_its_incidence():
    # θ and u₀ both bend the order: a calibration pins the mapping, not each of them, so the
    # stored incidence is reused with the stored u₀ (scaled with the pitch like F), never with
    # the spot's own u₀ — that pair is another mapping.
    grating = TiltedGrating(0.55, 3540.0, 23.25, axis_offset_px=-929.0)
    stored_optics = RigOptics(
        camera="NIKON D300S", focal_length_mm=31.0, pixel_pitch_um=10.4, order_angle_deg=0.0
    )
    stored = RigGeometry(grating, stored_optics)
    same = replace(stored_optics, axis_offset_px=150.0)
    prior, _ = rig_prior(same, stored=stored)
    assert prior is not None
    mean, sigma = prior.values["axis_offset_px"]
    assert mean == pytest.approx(-929.0) and prior.axis_offset_px == pytest.approx(-929.0)
    assert sigma == pytest.approx(3540.0 * math.tan(math.radians(1.0)))
    body = replace(same, camera="NIKON D5300", pixel_pitch_um=5.2)
    prior, why = rig_prior(body, stored=stored)
    assert prior is not None and "the same lens" in why
    assert prior.values["axis_offset_px"][0] == pytest.approx(-929.0 * 2.0)
    # The other first order: the same grating with θ → −θ and u₀ → −u₀.
    prior, _ = rig_prior(replace(body, side=-1), stored=stored)
    assert prior is not None
    assert prior.values["axis_offset_px"][0] == pytest.approx(929.0 * 2.0)
    assert prior.values["incidence_deg"][0] == pytest.approx(-23.25)
    # Another lens: nothing of the stored angles is reused, u₀ is the spot's.
    prior, _ = rig_prior(replace(same, focal_length_mm=50.0), stored=stored)
    assert prior is not None and prior.values["axis_offset_px"][0] == pytest.approx(150.0)


def test_one_led_through_a_stored_geometry_lands_on_its_mapping():
    # A calibration's fitted pair (θ 23°, u₀ −929 px) for a rig whose truth is θ −9.4°, u₀ 0:
    # the same mapping to 2 nm. Reused with the spot's u₀ instead, the LED search landed 6.6 nm
    # off; with its own u₀, on the truth.
    truth = TiltedGrating(0.4778, 3045.0, -9.36)
    stored = TiltedGrating(0.5502, 3540.7, 23.25, axis_offset_px=-929.2)
    low, high = truth.pixel_at([365.0, 765.0])
    pixel = np.arange(np.floor(low), np.ceil(high), 2.0)
    name = "Canon EOS 5D Mark II"
    camera = find_camera(colour_science_cameras(), name).sensitivity
    led = render_observation(
        colour_lamp("LED-B3"), camera, mapping=truth, pixel=pixel, kind="led"
    ).observation
    optics = {"focal_length_mm": 31.0, "pixel_pitch_um": 10.0}
    led = replace(led, pixel_origin="direct_spot", metadata={"optics": optics})
    rig = RigGeometry(stored, RigOptics(focal_length_mm=31.0, pixel_pitch_um=10.0))
    found = locate_mapping(
        [led], fallback_camera_basis(exclude=[name]).prior(), DEFAULT_GRID, stored=rig
    )
    true_nm = truth.wavelength_nm(pixel)
    inside = (true_nm >= DEFAULT_GRID.start_nm) & (true_nm <= DEFAULT_GRID.stop_nm)
    assert np.mean(np.abs(found.mapping.wavelength_nm(pixel) - true_nm)[inside]) < 1.0


def test_grating_file_carries_the_rig_and_reads_version_one(tmp_path):
    rig = RigGeometry(
        TiltedGrating(0.3, 7300.0, 3.5), RigOptics(camera="NIKON D7000", focal_length_mm=35.0)
    )
    grating = GratingEfficiency(
        np.array([400.0, 700.0]), np.array([1.0, 0.5]), geometry={"rig": rig.to_dict()}
    )
    path = write_grating_file(tmp_path / "grating.json", grating)
    document = json.loads(path.read_text())
    assert document["format_version"] == GRATING_FORMAT_VERSION == 2
    back = read_grating_file(path)
    assert back.rig is not None
    assert RigGeometry.from_dict(back.rig).grating == rig.grating
    # Version 1 (no rig) still reads.
    document["format_version"] = 1
    del document["geometry"]["rig"]
    path.write_text(json.dumps(document))
    assert read_grating_file(path).rig is None
    # A malformed rig is named.
    document["format_version"] = 2
    document["geometry"]["rig"] = {"grating": {"dispersion_nm_per_px": -1}}
    path.write_text(json.dumps(document))
    with pytest.raises(GratingFileError, match=r"geometry\.rig\.grating"):
        read_grating_file(path)


def test_a_line_groups_fit_jacobian_equals_finite_differences(monkeypatch):
    """The feature fit's closed-form Jacobian (shared shift of a blend's components, width,
    background, heights) against central differences, for a blend of two lines and a single one."""
    import calib.wavelength.features as features
    from calib.core.line_lists import Line, blends

    captured = []
    real = levenberg_marquardt

    def recording(function, x0, **options):
        captured.append((function, np.array(x0)))
        return real(function, x0, **options)

    monkeypatch.setattr(features, "levenberg_marquardt", recording)
    mapping = QuadraticMapping(0.0, 0.5, 400.0, pixel_range=(0.0, 400.0))
    lines = [
        Line("A 540", 540.0, 1.0, "A"),
        Line("B 542.5", 542.5, 0.6, "B"),
        Line("C 548", 548.0, 0.8, "C"),
    ]
    group = blends(lines, 3.0)
    assert sorted(len(b.lines) for b in group) == [1, 2]
    pixel = np.arange(0.0, 400.0)
    sigma = 2.5 / 2.355
    signal = np.zeros(pixel.size)
    signal += sum(
        line.strength
        * np.exp(-0.5 * ((pixel - (line.wavelength_nm - 400.0) / 0.5 - 0.3) / sigma) ** 2)
        for line in lines
    )
    fitted = features._fit_group(pixel, signal + 0.01, 0.01, group, mapping, 2.5, 1.0)
    assert fitted and captured
    function, x0 = captured[0]
    x = x0 + 0.05  # away from the start: nonzero shifts, another width and heights
    _, deferred = function(x, True)
    jacobian = deferred()  # the fit asks for it at the trials it accepts only
    numeric = _central_difference(lambda v: function(v, False)[0], x, 1e-6)
    np.testing.assert_allclose(jacobian, numeric, rtol=1e-5, atol=1e-5 * np.abs(numeric).max())
