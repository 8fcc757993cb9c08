"""The default camera basis: the bundled rawtoaces-data cameras when no other data is present, the
Solomatov & Akkaynak ground truths with rawtoaces-data's other bodies (one body, one weight) when they
are; ``--exclude-camera`` keeps a camera out of it for real; the 12-curve fallback always warns."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.core import datasets
from calib.core.camera_bodies import default_body_index, names_camera
from calib.core.datasets import (
    BUTCHERG,
    DATA_DIR_ENV,
    RAWTOACES_DATA,
    REFERENCE_COLLECTIONS,
    SOLOMATOV,
    exclude_cameras,
    load_collection,
    new_bodies,
    reference_cameras,
)
from calib.core.errors import InputError
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum
from calib.model.bases import FALLBACK_WARNING, default_camera_basis, fallback_camera_basis

BUNDLED = load_collection(RAWTOACES_DATA)
#: Solomatov & Akkaynak file names for three bodies rawtoaces-data also has (one under a market
#: name) and one it lacks.
SOLOMATOV_FILES = {
    "Canon_600D_Jiang-et-al-2013.csv": "Canon EOS 600D",
    "Nikon_D700_Jiang-et-al-2013.csv": "Nikon D700",
    "Canon_400D_Jiang-et-al-2013.csv": "Canon Digital Rebel XTi",
    "Pentax_K5_Jiang-et-al-2013.csv": "Nikon D70",  # a body rawtoaces-data lacks
}


@pytest.fixture
def no_data(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """No data directory anywhere: not given, $SPECTRAL_RIG_DATA unset, an empty user cache."""
    monkeypatch.delenv(DATA_DIR_ENV, raising=False)
    monkeypatch.setattr(datasets, "default_data_dir", lambda: tmp_path / "absent")
    return tmp_path


def _solomatov_dir(root: Path) -> Path:
    folder = root / SOLOMATOV / "data" / "ground-truths"
    folder.mkdir(parents=True)
    by_camera = {record.camera: record for record in BUNDLED}
    for file_name, source in SOLOMATOV_FILES.items():
        curves = by_camera[source].sensitivity.resample(DEFAULT_GRID)
        rows = ["wavelength,red,green,blue", *_rows(curves)]
        (folder / file_name).write_text("\n".join(rows) + "\n")
    return root


def test_without_data_the_basis_is_the_bundled_rawtoaces_data(no_data: Path) -> None:
    reference = reference_cameras()
    assert len(reference.records) == len(BUNDLED) == 52
    assert {r.collection for r in reference.records} == {RAWTOACES_DATA}
    assert "bundled" in reference.source
    basis = default_camera_basis()
    assert len(basis.camera_names) == 52 and basis.source == reference.source
    assert basis.fallback == reference.fallback


def test_a_named_data_directory_that_does_not_exist_is_an_error(no_data: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        reference_cameras(no_data / "typo")


def _rows(curves: MultiSpectrum) -> list[str]:
    return [
        f"{wavelength:g},{r:.6f},{g:.6f},{b:.6f}"
        for wavelength, (r, g, b) in zip(curves.wavelength_nm, curves.values, strict=True)
    ]


def test_with_solomatov_the_default_basis_is_the_ground_truths(tmp_path: Path) -> None:
    root = _solomatov_dir(tmp_path / "data")
    assert REFERENCE_COLLECTIONS == (SOLOMATOV,)  # decision 0027's measurement
    reference = reference_cameras(root)
    assert [r.collection for r in reference.records] == [SOLOMATOV] * 4
    assert reference.fallback is None and reference.source == f"{SOLOMATOV} ground truths (4)"
    assert default_camera_basis(data_dir=root, n_vectors=3).fallback is None


def test_rawtoaces_data_joins_the_ground_truths_with_only_the_bodies_they_lack(
    tmp_path: Path,
) -> None:
    root = _solomatov_dir(tmp_path / "data")
    reference = reference_cameras(root, collections=(SOLOMATOV, RAWTOACES_DATA))
    solomatov = [r for r in reference.records if r.collection == SOLOMATOV]
    added = [r for r in reference.records if r.collection == RAWTOACES_DATA]
    assert len(solomatov) == 4 and reference.fallback is None
    index = default_body_index()
    bodies = [index.body(r.camera) for r in reference.records]
    assert len(bodies) == len(set(bodies))  # one body, one weight
    # 600D, D700 and the 400D (rawtoaces-data's "Digital Rebel XTi") are not added again
    assert len(added) == 52 - 3
    duplicates = ("Canon EOS 600D", "Nikon D700", "Canon Digital Rebel XTi")
    assert not any(r.camera in duplicates for r in added)
    assert f"{RAWTOACES_DATA} bodies not among them (49)" in reference.source


def test_without_solomatov_other_collections_add_their_new_bodies_to_the_bundled_ones(
    tmp_path: Path,
) -> None:
    folder = tmp_path / "data" / BUTCHERG / "Canon" / "600D"
    folder.mkdir(parents=True)
    by_camera = {record.camera: record for record in BUNDLED}
    for camera, source in (("Canon EOS 600D", "Canon EOS 600D"), ("Olympus E-PL2", "Nikon D70")):
        rows = _rows(by_camera[source].sensitivity.resample(DEFAULT_GRID))
        text = f"#Camera: {camera}\n" + "\n".join(rows) + "\n"
        (folder / f"{camera.replace(' ', '_')}.csv").write_text(text)
    reference = reference_cameras(tmp_path / "data", collections=(SOLOMATOV, BUTCHERG))
    assert [r.camera for r in reference.records if r.collection == BUTCHERG] == ["Olympus E-PL2"]
    assert len(reference.records) == 53
    assert reference.fallback is not None and f"no {SOLOMATOV} in" in reference.fallback
    assert reference.source.startswith(f"{RAWTOACES_DATA} cameras (52, bundled) + {BUTCHERG}")


def test_new_bodies_keeps_the_first_record_of_each_body() -> None:
    twice = [BUNDLED[0], BUNDLED[0], BUNDLED[1]]
    assert new_bodies(twice, []) == [BUNDLED[0], BUNDLED[1]]
    assert new_bodies(twice, [BUNDLED[1]]) == [BUNDLED[0]]


@pytest.mark.parametrize(
    ("pattern", "removed"),
    [
        ("Canon 600D", {"Canon EOS 600D"}),
        ("canon eos-600d", {"Canon EOS 600D"}),
        ("Canon Rebel T3i", {"Canon EOS 600D"}),  # the same body's market name
        ("Nikon D70", {"Nikon D70"}),  # not the D700 nor the D7000
        ("Canon EOS 5D Mark II", {"Canon EOS 5D Mark II"}),
        ("Canon 5D Mk II", {"Canon EOS 5D Mark II"}),
        ("nikon d7*", {"Nikon D70", "Nikon D700", "Nikon D7000"}),
        ("Hasselblad*", {"Hasselblad L1D-20c", "Hasselblad L2D-20c"}),
    ],
)
def test_a_pattern_names_a_body_or_a_wildcard(pattern: str, removed: set[str]) -> None:
    kept, excluded = exclude_cameras(BUNDLED, [pattern])
    assert {r.camera for r in excluded} == removed
    assert len(kept) + len(excluded) == len(BUNDLED)
    assert all(not names_camera(pattern, r.camera) for r in kept)


def test_exclude_camera_really_removes_it_from_the_basis(no_data: Path) -> None:
    full = default_camera_basis()
    without = default_camera_basis(exclude=["Nikon D5100", "Sony*"])
    assert "Nikon D5100 (rawtoaces-data)" in full.camera_names
    assert "Nikon D5100 (rawtoaces-data)" not in without.camera_names
    assert not any(name.startswith("Sony") for name in without.camera_names)
    assert len(without.camera_names) == 52 - 1 - 11
    assert without.exclusions == ("Nikon D5100", "Sony*")
    assert "Nikon D5100 (rawtoaces-data)" in without.excluded_cameras
    assert "without Nikon D5100 (rawtoaces-data)" in without.source
    assert without.content_hash != full.content_hash
    # the prior differs: the excluded camera no longer shapes it
    assert not np.allclose(without.prior().mean, full.prior().mean)
    record = without.to_dict()
    assert record["exclusions"] == ["Nikon D5100", "Sony*"]


def test_an_exclusion_that_names_no_camera_is_among_the_basis_warnings(no_data: Path) -> None:
    """A misspelt camera under test ('Nikon D5010') kept nothing out, silently: every result on
    the basis (rig estimate, calib estimate, rig grating, calib plan-lamps) now says so."""
    basis = default_camera_basis(exclude=["Nikon D5100", "Nikon D5010", "sony*"])
    assert basis.unmatched_exclusions == ("Nikon D5010",)
    assert basis.to_dict()["unmatched_exclusions"] == ["Nikon D5010"]
    fallback, unmatched = basis.warnings()
    assert fallback == basis.fallback
    assert unmatched.startswith(
        "--exclude-camera 'Nikon D5010' names none of the 52 cameras the basis draws on and "
        "kept nothing out"
    )
    assert default_camera_basis(exclude=["Nikon D5100"]).warnings() == [basis.fallback]


def test_an_exclusion_that_leaves_too_few_cameras_is_an_error(no_data: Path) -> None:
    with pytest.raises(InputError, match="--exclude-camera") as caught:
        default_camera_basis(exclude=["*"])
    assert "leaves 0 of 52" in str(caught.value)


def test_the_12_curve_fallback_always_carries_its_warning() -> None:
    basis = fallback_camera_basis(exclude=["Nikon 5100"], variants_per_curve=1, cache=False)
    assert basis.fallback == FALLBACK_WARNING
    assert basis.to_dict()["fallback"] == FALLBACK_WARNING
    assert basis.excluded_cameras == ("Nikon 5100 (NPL)",)


def test_calib_validate_keeps_an_excluded_camera_out_of_every_basis(tmp_path: Path) -> None:
    from calib.core.datasets import MAKABE2025_TEST_FILES
    from calib.evaluation.validation.splits import load_splits

    folder = tmp_path / SOLOMATOV / "data" / "ground-truths"
    folder.mkdir(parents=True)
    rows = ["wavelength,red,green,blue", *_rows(BUNDLED[0].sensitivity.resample(DEFAULT_GRID))]
    for name in (*MAKABE2025_TEST_FILES, "Camera_3_Someone-2020.csv", "Camera_4_Someone-2020.csv"):
        (folder / name).write_text("\n".join(rows) + "\n")
    splits, notes = load_splits(tmp_path, exclude=["Camera 3"], out_of_basis=False)
    assert [r.name for r in splits.validation.training] == ["Camera 4 (Someone-2020)"]
    assert [c.name for c in splits.validation.cameras] == ["Camera 4 (Someone-2020)"]
    assert "kept out of every basis by --exclude-camera: Camera 3 (Someone-2020)" in notes
