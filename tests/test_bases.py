import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.spectra import DEFAULT_GRID
from calib.model.bases import camera_basis, fallback_camera_basis, fourier_basis
from tests.synthetic_cameras import spanning_set


def test_svd_basis_is_orthonormal_and_cached(tmp_path):
    cameras = spanning_set()
    basis = camera_basis(cameras, n_vectors=4, cache_dir=tmp_path)
    for channel in range(3):
        gram = basis.channel(channel).T @ basis.channel(channel)
        np.testing.assert_allclose(gram, np.eye(4), atol=1e-12)
    cached = list((tmp_path / "bases").glob("*.npz"))
    assert len(cached) == 1 and basis.content_hash in cached[0].name
    again = camera_basis(cameras, n_vectors=4, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.vectors, basis.vectors)
    peaks = cameras.reshape(7, -1).max(axis=1)[:, None, None]
    np.testing.assert_allclose(basis.mean, (cameras / peaks).mean(axis=0), atol=1e-12)


def test_basis_reconstructs_training_cameras_exactly_with_full_rank(tmp_path):
    cameras = spanning_set()
    basis = camera_basis(cameras, n_vectors=7, cache_dir=tmp_path)
    normalised = cameras[2] / cameras[2].max()
    np.testing.assert_allclose(basis.project(normalised), normalised, atol=1e-12)


def test_basis_rejects_too_many_vectors(tmp_path):
    with pytest.raises(InputError, match="n_vectors"):
        camera_basis(spanning_set(), n_vectors=8, cache_dir=tmp_path)


def test_fourier_basis_conventions():
    paired = fourier_basis(DEFAULT_GRID, 7)
    assert paired.shape == (31, 7)
    np.testing.assert_allclose(paired[:, 0], 1.0)
    t = (DEFAULT_GRID.wavelength_nm - 400) / 300
    np.testing.assert_allclose(paired[:, 1], np.cos(2 * np.pi * t), atol=1e-12)
    np.testing.assert_allclose(paired[:, 4], np.sin(4 * np.pi * t), atol=1e-12)
    paper = fourier_basis(DEFAULT_GRID, 3, convention="paper")
    np.testing.assert_allclose(
        paper[:, 2], np.sin(4 * np.pi * DEFAULT_GRID.wavelength_nm / 300), atol=1e-12
    )


def test_fallback_basis_excludes_the_camera_under_test(tmp_path):
    basis = fallback_camera_basis(exclude=["Nikon 5100"], cache_dir=tmp_path)
    assert not any("nikon 5100" in name.lower() for name in basis.camera_names)
    assert "excluding Nikon 5100" in basis.source
    assert basis.vectors.shape == (3, 31, 7)


def test_the_prior_distance_ignores_scale_and_is_zero_at_the_mean(tmp_path):
    from calib.model.bases import prior_distance
    from tests.synthetic_cameras import exact_basis

    basis, cameras = exact_basis(tmp_path)
    prior = basis.prior()
    assert prior_distance(prior, 3.0 * prior.mean) == pytest.approx(0.0, abs=1e-9)
    assert prior_distance(prior, 2.0 * cameras[0]) == pytest.approx(
        prior_distance(prior, cameras[0])
    )
    assert np.isfinite(basis.typical_distance) and basis.typical_distance > 0


def test_a_camera_s_perturbed_variants_are_left_out_with_it():
    from calib.model.bases import ledoit_wolf_shrinkage, typical_distance

    rng = np.random.default_rng(0)
    grid = DEFAULT_GRID
    cameras = rng.uniform(0.1, 1.0, size=(6, grid.size, 3))
    twins = np.concatenate([cameras, cameras + rng.normal(0, 1e-3, cameras.shape)])
    groups = [f"camera {i}" for i in range(6)] * 2
    weights = np.array([ledoit_wolf_shrinkage(twins[:, :, c]) for c in range(3)])
    grouped = typical_distance(twins, weights, grid, groups)
    apart = typical_distance(twins, weights, grid, [f"curve {i}" for i in range(12)])
    # Left out alone, each curve still has its near-copy in the prior: it looks typical.
    assert grouped > 3 * apart


def test_camera_groups_come_from_the_basis_not_from_names(tmp_path):
    rng = np.random.default_rng(1)
    grid = DEFAULT_GRID
    cameras = rng.uniform(0.1, 1.0, size=(6, grid.size, 3))
    twins = np.concatenate([cameras, cameras + rng.normal(0, 1e-3, cameras.shape)])
    # real cameras whose names merely end like a fallback variant's stay apart
    names = [f"camera {i}" for i in range(6)] + [f"camera {i} variant 1" for i in range(6)]
    by_name = camera_basis(twins, n_vectors=4, camera_names=names, cache_dir=tmp_path)
    apart = camera_basis(twins, n_vectors=4, camera_names=[f"c{i}" for i in range(12)], cache=False)
    assert by_name.typical_distance == pytest.approx(apart.typical_distance)
    grouped = camera_basis(
        twins, n_vectors=4, camera_names=names, groups=names[:6] * 2, cache_dir=tmp_path
    )
    assert grouped.content_hash != by_name.content_hash
    assert grouped.typical_distance > 3 * by_name.typical_distance
    with pytest.raises(InputError, match="5 group labels for 12 cameras"):
        camera_basis(twins, n_vectors=4, groups=names[:5], cache=False)


def test_fallback_variants_are_grouped_with_their_camera(monkeypatch):
    import calib.model.bases

    seen = []
    original = calib.model.bases.typical_distance

    def spy(curves, weights, grid, groups):
        seen.append(list(groups))
        return original(curves, weights, grid, groups)

    monkeypatch.setattr(calib.model.bases, "typical_distance", spy)
    basis = fallback_camera_basis(variants_per_curve=2, cache=False)
    (groups,) = seen
    assert groups == [name.split(" variant ")[0] for name in basis.camera_names]
    assert len(set(groups)) * 3 == len(groups)
