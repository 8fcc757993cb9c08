"""Camera splits of the validation protocol: training, validation and test, never mixed.

``training``
    The basis' cameras: the Solomatov & Akkaynak ground truths outside the paper's 5 test cameras
    (44 curves of 36 bodies; Makabe et al. 2025 §4.1).
``validation`` (:class:`ValidationSplit`)
    Leave one *body* out over the training collection: each training curve is estimated with a
    basis of every training curve of the *other* bodies (a body measured twice leaves with both
    curves). Optionally also some of Solomatov & Akkaynak's *predicted* curves (estimates from
    DNG colour matrices: plausible cameras, not measurements), each with its body left out of the
    basis likewise, and none of a test body. The only cameras a tuning choice may look at
    (:func:`require_validation`).
``test`` (:class:`TestSplit`)
    Reported, never tuned on: the paper's 5 test cameras; every measured camera of the other
    collections (rawtoaces-data, rawtoaces, camspec, butcherg) whose body is not in the training
    set, one curve per body (de-duplicated by :class:`calib.core.camera_bodies.BodyIndex`, keeping
    the first of: the paper's curve, rawtoaces-data, rawtoaces, camspec, butcherg); and
    out-of-basis cameras (colour-science's Foveon Sigma SDMerill and a test camera behind a blue
    filter, :func:`calib.evaluation.synthetic.out_of_basis_cameras`). Its basis is the whole
    training set; a test body that is in training (or shares its sensor, by the alias tables) is
    refused on construction.

Every decision (who was left out and why) is kept as a :class:`SplitNote` and printed with the
tables (:meth:`Split.describe`).
"""

from __future__ import annotations

import zlib
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np

from calib.core.camera_bodies import BodyIndex, read_rawtoaces_aliases
from calib.core.datasets import (
    BUTCHERG,
    CAMSPEC,
    COLOUR_SCIENCE,
    RAWTOACES,
    RAWTOACES_DATA,
    SOLOMATOV,
    SOLOMATOV_PREDICTIONS,
    CameraRecord,
    exclude_cameras,
    load_collection,
    makabe2025_split,
    resolve_data_dir,
)
from calib.core.errors import InputError
from calib.core.spectra import MultiSpectrum

SplitRole = Literal["validation", "test"]
#: Collections whose measured cameras join the test split, in the order a duplicate body is kept.
TEST_COLLECTIONS: tuple[str, ...] = (RAWTOACES_DATA, RAWTOACES, CAMSPEC, BUTCHERG)

#: Groups of cameras within a split (a column of the tables).
LEAVE_ONE_OUT = "leave-one-body-out"
PREDICTION = "predicted curve"
PAPER_TEST = "paper test"
OTHER_COLLECTIONS = "other collections"
OUT_OF_BASIS = "out of basis"
#: Validation cameras changed physically (:mod:`calib.evaluation.validation.transforms`).
TRANSFORMED = "physically transformed"


class SplitRoleError(InputError):
    """A split was passed where its role forbids it (e.g. a test split to a tuning routine)."""


@dataclass(frozen=True, eq=False)
class SplitCamera:
    """One camera of a split.

    Attributes
    ----------
    name
        The record's name (camera and source), e.g. ``"Canon 600D (Jiang-et-al-2013)"``.
    body
        Its body key (:meth:`calib.core.camera_bodies.BodyIndex.body`).
    collection, group
        Where it comes from, and its group in the split (:data:`LEAVE_ONE_OUT` …).
    sensitivity
        R, G, B curves, maximum 1.
    """

    name: str
    body: str
    collection: str
    group: str
    sensitivity: MultiSpectrum

    @property
    def stable_id(self) -> int:
        """A number of the name alone (the camera's scenes do not depend on the split's order)."""
        return zlib.crc32(self.name.encode("utf-8"))


@dataclass(frozen=True)
class SplitNote:
    """A camera left out of a split, and why."""

    camera: str
    collection: str
    reason: str


@dataclass(frozen=True, eq=False)
class Split:
    """Cameras of one role, the training set their bases come from, and the decisions made.

    Attributes
    ----------
    cameras
        The split's cameras, in a fixed order.
    training
        The training records (the basis' cameras) and, aligned, their body keys.
    notes
        Cameras left out, with the reason.
    """

    role: ClassVar[SplitRole]
    cameras: tuple[SplitCamera, ...]
    training: tuple[CameraRecord, ...]
    training_bodies: tuple[str, ...]
    notes: tuple[SplitNote, ...] = ()

    def basis_records(self, camera: SplitCamera) -> tuple[CameraRecord, ...]:
        """The training curves a basis for ``camera`` is built from: all but its own body's."""
        return tuple(
            record
            for record, body in zip(self.training, self.training_bodies, strict=True)
            if body != camera.body
        )

    def describe(self) -> list[str]:
        """Markdown lines: what the split holds, by group and collection, and what was left out."""
        bodies = len(set(self.training_bodies))
        lines = [
            f"**Split: {self.role}** — {len(self.cameras)} cameras. Basis (training): "
            f"{len(self.training)} curves of {bodies} bodies"
            + (
                ", each camera's own body left out of its basis."
                if self.role == "validation"
                else ", none of them a test body."
            )
        ]
        groups = Counter(camera.group for camera in self.cameras)
        for group, count in groups.items():
            members = [c for c in self.cameras if c.group == group]
            collections = Counter(c.collection for c in members)
            lines.append(
                f"- {group}: {count} ("
                + ", ".join(f"{name} {n}" for name, n in collections.items())
                + "): "
                + "; ".join(c.name for c in members)
            )
        by_reason: dict[str, list[SplitNote]] = {}
        for note in self.notes:
            by_reason.setdefault(note.reason.split(" (")[0], []).append(note)
        for reason, notes in by_reason.items():
            lines.append(
                f"- left out, {reason} ({len(notes)}): "
                + "; ".join(
                    note.camera
                    + (f" ({note.reason.split(' (', 1)[1]}" if " (" in note.reason else "")
                    for note in notes
                )
            )
        return lines


@dataclass(frozen=True, eq=False)
class ValidationSplit(Split):
    """The cameras tuning may look at (module docstring)."""

    role: ClassVar[SplitRole] = "validation"


@dataclass(frozen=True, eq=False)
class TestSplit(Split):
    """The cameras reported only (module docstring). Refuses a camera whose body is in training."""

    role: ClassVar[SplitRole] = "test"
    __test__: ClassVar[bool] = False  # not a pytest test class, whatever its name

    def __post_init__(self) -> None:
        leaked = sorted({c.name for c in self.cameras if c.body in set(self.training_bodies)})
        if leaked:
            raise SplitRoleError(
                f"test cameras {leaked} have a body in the training set", source="test split"
            )


def require_validation(split: Split) -> ValidationSplit:
    """``split`` if it is the validation split, else :class:`SplitRoleError`.

    Every routine that *chooses* something (a default, a weight, a threshold) calls this first: a
    test camera cannot reach a tuning decision by accident.
    """
    if not isinstance(split, ValidationSplit):
        raise SplitRoleError(
            f"tuning may only look at the validation split, got the {split.role} split; test "
            "cameras are for reporting",
            source="split",
        )
    return split


@dataclass(frozen=True, eq=False)
class Splits:
    """The three splits of one data directory."""

    validation: ValidationSplit
    test: TestSplit


def _camera(record: CameraRecord, index: BodyIndex, group: str) -> SplitCamera:
    return SplitCamera(
        record.name, index.body(record.camera), record.collection, group, record.sensitivity
    )


def make_splits(
    training: Sequence[CameraRecord],
    paper_test: Sequence[CameraRecord],
    other_collections: Sequence[CameraRecord],
    out_of_basis: Sequence[tuple[str, MultiSpectrum]] = (),
    predictions: Sequence[CameraRecord] = (),
    index: BodyIndex | None = None,
) -> Splits:
    """Build the splits from records (module docstring); ``other_collections`` in priority order.

    Raises
    ------
    InputError
        A paper test camera whose body is in the training set (the data are not the paper's).
    """
    index = index or BodyIndex()
    training_bodies = tuple(index.body(r.camera) for r in training)
    training_sensors = {index.sensor(r.camera): r.name for r in training}
    notes: list[SplitNote] = []
    kept: dict[str, str] = {}
    test_cameras: list[SplitCamera] = []
    for record in paper_test:
        camera = _camera(record, index, PAPER_TEST)
        if camera.body in training_bodies:
            raise InputError(
                f"the paper's test camera {record.name} is also a training body", source=SOLOMATOV
            )
        kept[camera.body] = record.name
        test_cameras.append(camera)
    for record in other_collections:
        camera = _camera(record, index, OTHER_COLLECTIONS)
        sensor = index.sensor(record.camera)
        if camera.body in training_bodies:
            reason = "in training (same body)"
        elif sensor in training_sensors:
            reason = f"in training (shares a sensor with {training_sensors[sensor]})"
        elif camera.body in kept:
            reason = f"duplicate body (kept {kept[camera.body]})"
        else:
            kept[camera.body] = record.name
            test_cameras.append(camera)
            continue
        notes.append(SplitNote(record.name, record.collection, reason))
    for name, sensitivity in out_of_basis:
        test_cameras.append(
            SplitCamera(name, f"out-of-basis:{name}", COLOUR_SCIENCE, OUT_OF_BASIS, sensitivity)
        )
    # A predicted curve of a test body would let the test camera's shape into tuning decisions.
    validation_cameras = [_camera(r, index, LEAVE_ONE_OUT) for r in training]
    validation_notes: list[SplitNote] = []
    for record in predictions:
        camera = _camera(record, index, PREDICTION)
        if camera.body in kept:
            validation_notes.append(
                SplitNote(record.name, record.collection, f"a test body ({kept[camera.body]})")
            )
        else:
            validation_cameras.append(camera)
    training_records = tuple(training)
    return Splits(
        ValidationSplit(
            tuple(validation_cameras), training_records, training_bodies, tuple(validation_notes)
        ),
        TestSplit(tuple(test_cameras), training_records, training_bodies, tuple(notes)),
    )


def transformed_cameras(cameras: Sequence[SplitCamera], count: int, seed: int) -> list[SplitCamera]:
    """``count`` transformed copies of ``cameras``, the bases drawn in turn from a shuffled order
    and the kinds in turn, all from ``seed``; each keeps its base's body and collection."""
    from calib.evaluation.validation.transforms import TRANSFORM_KINDS, transform_camera

    if count <= 0 or not cameras:
        return []
    rng = np.random.default_rng([seed, 94])
    order = rng.permutation(len(cameras))
    out: list[SplitCamera] = []
    for k in range(count):
        base = cameras[int(order[k % len(cameras)])]
        kind = TRANSFORM_KINDS[k % len(TRANSFORM_KINDS)]
        sensitivity, text = transform_camera(base.sensitivity, kind, rng)
        out.append(
            replace(base, name=f"{base.name} · {text}", group=TRANSFORMED, sensitivity=sensitivity)
        )
    return out


def load_splits(
    data_dir: str | Path | None = None,
    *,
    predictions: int = 0,
    seed: int = 0,
    out_of_basis: bool = True,
    exclude: Sequence[str] = (),
    transformed: int = 0,
) -> tuple[Splits, list[str]]:
    """The splits of a data directory, and notes on collections that are missing.

    Parameters
    ----------
    data_dir
        The camera data directory (:func:`calib.core.datasets.resolve_data_dir`); the
        Solomatov & Akkaynak collection is required, the others are used when present.
    predictions
        How many of Solomatov & Akkaynak's predicted curves join the validation split (drawn
        without replacement with ``seed``; 0: none).
    out_of_basis
        Add the Foveon camera and the first paper test camera behind a blue filter to the test split.
    exclude
        Patterns of training cameras to keep out of every basis (``--exclude-camera``,
        :func:`calib.core.datasets.exclude_cameras`); they leave the validation split with them.
    transformed
        How many physically transformed validation cameras join the validation split (IR-cut
        edge, blue edge, dye shifts, colour filters: :mod:`calib.evaluation.validation.transforms`,
        drawn with ``seed`` from the split's other cameras; decision 0094).
    """
    from calib.evaluation.synthetic import out_of_basis_cameras

    root = resolve_data_dir(data_dir)
    training, paper_test = makabe2025_split(root)
    missing: list[str] = []
    if exclude:
        training, excluded = exclude_cameras(training, exclude)
        missing.append(
            f"kept out of every basis by --exclude-camera: "
            f"{', '.join(record.name for record in excluded) or 'no training camera matched'}"
        )
    others: list[CameraRecord] = []
    for collection in TEST_COLLECTIONS:
        try:
            others.extend(load_collection(collection, root))
        except InputError as exc:
            missing.append(f"{collection}: {exc}")
    alias_file = root / RAWTOACES_DATA / "data" / "aliases.json"
    aliases = read_rawtoaces_aliases(alias_file if alias_file.is_file() else None)
    predicted: list[CameraRecord] = []
    if predictions > 0:
        pool = load_collection(SOLOMATOV_PREDICTIONS, root)
        chosen = np.random.default_rng(seed).choice(
            len(pool), min(predictions, len(pool)), replace=False
        )
        predicted = [pool[int(i)] for i in sorted(chosen)]
    extra = (
        out_of_basis_cameras(paper_test[0].camera, paper_test[0].sensitivity)
        if out_of_basis
        else []
    )
    splits = make_splits(training, paper_test, others, extra, predicted, BodyIndex(aliases))
    if transformed > 0:
        validation = splits.validation
        added = transformed_cameras(validation.cameras, transformed, seed)
        splits = Splits(replace(validation, cameras=(*validation.cameras, *added)), splits.test)
    return splits, missing
