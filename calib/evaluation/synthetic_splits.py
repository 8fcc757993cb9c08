"""The paper-reproduction protocol (:mod:`calib.evaluation.synthetic`) on the validation split's cameras.

Kept apart from the protocol: the splits (:mod:`calib.evaluation.validation.splits`) use the protocol's
out-of-basis cameras, so the protocol cannot import them back.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from calib.core.datasets import makabe2025_split
from calib.core.spectra import DEFAULT_GRID, MultiSpectrum, WavelengthGrid
from calib.evaluation.validation.splits import load_splits
from calib.model.bases import CameraBasis, camera_basis, default_camera_basis


def validation_cameras(
    data_dir: str | Path | None = None,
    *,
    grid: WavelengthGrid = DEFAULT_GRID,
    n_vectors: int = 7,
    exclude: Sequence[str] = (),
    predictions: int = 0,
    seed: int = 0,
    group: str | None = None,
) -> tuple[list[tuple[str, MultiSpectrum]], Callable[[str], CameraBasis], str]:
    """The validation split's measured cameras for the paper's protocol: every training curve, each
    with a basis of the training curves of the *other* bodies (leave one body out,
    :class:`calib.evaluation.validation.splits.ValidationSplit`), the only cameras a tuning choice
    made on this protocol may look at.

    ``predictions`` of the split's predicted curves join them (drawn with ``seed``); ``group``
    keeps one group of cameras only (e.g. the predicted curves alone).

    Returns ``(name, sensitivity)`` pairs, the basis of a camera by its name (built once per left-out
    body) and a description of the bases.
    """
    splits, _missing = load_splits(
        data_dir, out_of_basis=False, exclude=exclude, predictions=predictions, seed=seed
    )
    split = splits.validation
    chosen = [camera for camera in split.cameras if group is None or camera.group == group]
    by_name = {camera.name: camera for camera in chosen}
    bases: dict[tuple[str, ...], CameraBasis] = {}

    def basis_for(name: str) -> CameraBasis:
        records = split.basis_records(by_name[name])
        key = tuple(record.name for record in records)
        if key not in bases:
            bases[key] = camera_basis(
                [record.sensitivity for record in records],
                grid=grid,
                n_vectors=n_vectors,
                source=f"validation basis: {len(records)} training curves",
                camera_names=list(key),
            )
        return bases[key]

    cameras = [(camera.name, camera.sensitivity) for camera in chosen]
    return cameras, basis_for, "training curves, each camera's own body left out of its basis"


def paper_split_cameras(
    split: str, data_dir: str | Path | None = None
) -> tuple[list[tuple[str, MultiSpectrum]], CameraBasis | Callable[[str], CameraBasis]]:
    """The paper protocol's cameras of ``split`` and their basis, on the default grid:
    ``"validation"``, every training curve with its own body left out of its basis
    (:func:`validation_cameras`); ``"test"``, the paper's 5 test cameras with one basis of the
    other curves (:func:`calib.core.datasets.makabe2025_split`)."""
    if split == "validation":
        cameras, basis_for, _source = validation_cameras(data_dir)
        return cameras, basis_for
    _train, test = makabe2025_split(data_dir)
    basis = default_camera_basis(DEFAULT_GRID, data_dir=data_dir, exclude=[r.name for r in test])
    return [(r.camera, r.sensitivity) for r in test], basis
