"""Input sets: one estimate's inputs found from one path (a session directory, an inputs file).

A batch (:mod:`calib.pipeline.batch`) is a list of paths. An :class:`InputSetReader` recognises the
paths it can read and turns one into an :class:`InputSet`: the lamps, where the outputs go, the
caller's warnings and notes, the files it already verified and what it knows beyond them (the
truth). Running an input set is :func:`calib.pipeline.run_offline` with them, so a set estimated
in a batch gives what it gives on its own.

calib reads no session itself (it imports nothing of ``rig``): ``rig`` declares its reader of
session directories as the ``spectral_rig.inputs`` entry point ``session``, calib its reader of
inputs files (``calib estimate --inputs``'s YAML) as ``inputs`` (:data:`INPUTS_FILES`), and
:func:`input_set_readers` finds every reader installed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from calib.core.errors import InputError
from calib.pipeline.context import EstimateContext
from calib.pipeline.estimate import OfflineSettings
from calib.pipeline.inputs import LampInput
from calib.pipeline.inputs_file import own_settings_over, read_estimate_inputs
from calib.pipeline.outputs import check_out_dir
from calib.pipeline.progress import OfflineProgress
from calib.pipeline.provenance import InputFile
from calib.pipeline.run import OfflineOutcome, run_offline

#: The entry-point group of the installed readers (``pyproject.toml``).
INPUT_SET_ENTRY_POINTS = "spectral_rig.inputs"


@dataclass(frozen=True, eq=False)
class InputSet:
    """One estimate's inputs, ready for :func:`calib.pipeline.run_offline`.

    Parameters
    ----------
    name
        What a summary calls it (a session's directory name).
    lamps
        The lamps (:class:`~calib.pipeline.LampImages` or :class:`~calib.pipeline.LampProfile`).
    out_dir
        Where its outputs go, already checked by the reader.
    known_inputs
        Files the reader verified and hashed (not read again for the provenance).
    warnings, notes
        Recorded with the result (an incomplete session, which session it is).
    context
        The known truth and warm-up records, for the outputs and the report.
    settings
        :class:`~calib.pipeline.OfflineSettings` fields the set itself fixes (an inputs file's
        ``estimate:`` block: its method, grid, optics …); they override the batch's, except the
        options its command line typed (:func:`calib.pipeline.inputs_file.own_settings_over`).
    settings_source
        Where ``settings`` come from, for the warning when a typed option overrides one (the
        inputs file); default the set's name.
    """

    name: str
    lamps: tuple[LampInput, ...]
    out_dir: Path
    known_inputs: tuple[InputFile, ...] = ()
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    context: EstimateContext = field(default_factory=EstimateContext)
    settings: Mapping[str, Any] = field(default_factory=dict)
    settings_source: str | None = None

    def run(
        self,
        settings: OfflineSettings,
        *,
        progress: OfflineProgress | None = None,
        report: bool = True,
        prepare: Callable[[OfflineSettings], OfflineSettings] | None = None,
    ) -> OfflineOutcome:
        """Estimate and write the outputs: ``settings`` with the set's own fields (where the
        command line did not type them), warnings and notes (the set's first); ``prepare`` then
        completes them (a batch worker's basis for their grid and excluded cameras, resolved
        once per process: :func:`calib.pipeline.batch_jobs.worker_settings`)."""
        merged = own_settings_over(
            dataclasses.replace(
                settings,
                warnings=(*settings.warnings, *self.warnings),
                notes=(*settings.notes, *self.notes),
            ),
            self.settings,
            self.settings_source or self.name,
        )
        if prepare is not None:
            merged = prepare(merged)
        return run_offline(
            self.lamps,
            self.out_dir,
            merged,
            progress=progress,
            known_inputs=self.known_inputs,
            report=report,
            context=self.context,
        )


@runtime_checkable
class InputSetReader(Protocol):
    """Reads one kind of input set. Instances are pickled into the batch's workers by reference,
    so a reader is a module-level object of an importable module.

    Attributes
    ----------
    kind
        What it reads, in a word (``"session"``).
    description
        What it reads, for messages (``"a session directory (with log.jsonl)"``).
    """

    kind: str
    description: str

    def recognises(self, path: Path) -> bool:
        """Whether ``path`` is one of its input sets (cheap: no file is read beyond a name)."""

    def default_out_name(self, path: Path) -> str:
        """The set's name in a batch: its sub-directory of a batch's ``--out``."""

    def read(self, path: Path, out_dir: Path | None, *, force: bool) -> InputSet:
        """Check where the outputs go (``out_dir``, or the set's own default), then read and
        check the inputs.

        Raises
        ------
        calib.core.errors.CalibError
            Bad input (an :class:`~calib.core.errors.InputError` for what the user can fix).
        """


def input_set_readers() -> tuple[InputSetReader, ...]:
    """Every reader installed (the ``spectral_rig.inputs`` entry points), by name.

    Raises
    ------
    InputError
        An entry point that does not load or is not a reader (named).
    """
    readers: list[InputSetReader] = []
    for point in sorted(entry_points(group=INPUT_SET_ENTRY_POINTS), key=lambda p: p.name):
        try:
            reader = point.load()
        except ImportError as exc:
            raise InputError(
                f"the {point.name!r} input reader ({point.value}) cannot be imported: {exc}",
                source=INPUT_SET_ENTRY_POINTS,
            ) from None
        if not isinstance(reader, InputSetReader):
            raise InputError(
                f"{point.value} is not an input-set reader", source=INPUT_SET_ENTRY_POINTS
            )
        readers.append(reader)
    return tuple(readers)


def reader_for(path: Path, readers: Sequence[InputSetReader]) -> InputSetReader:
    """The reader that recognises ``path``.

    Raises
    ------
    InputError
        None does (named, with what is accepted).
    """
    for reader in readers:
        if reader.recognises(path):
            return reader
    if not path.exists():
        raise InputError("no such file or directory", source=str(path))
    accepted = " or ".join(reader.description for reader in readers) or "(no reader installed)"
    raise InputError(f"not {accepted}", source=str(path))


#: The suffixes of an inputs file.
INPUTS_FILE_SUFFIXES = (".yaml", ".yml")


class InputsFiles:
    """Inputs files (``calib estimate --inputs``'s YAML, :mod:`calib.pipeline.inputs_file`) as
    batch input sets: the ``spectral_rig.inputs`` entry point ``inputs``. A set's name is its
    folder's and the file's, ``<folder>-<stem>`` (one folder per camera, each with its
    ``lamps.yaml``, or several files in one folder: the names stay apart); without a batch
    ``--out`` its outputs go beside it, to ``<stem>-estimate/``."""

    kind = "inputs"
    description = "an inputs file (YAML with lamps:)"

    def recognises(self, path: Path) -> bool:
        """A file named ``*.yaml`` or ``*.yml``."""
        return Path(path).suffix.lower() in INPUTS_FILE_SUFFIXES and Path(path).is_file()

    def default_out_name(self, path: Path) -> str:
        file = Path(path)
        return f"{file.parent.name}-{file.stem}" if file.parent.name else file.stem

    def read(self, path: Path, out_dir: Path | None, *, force: bool) -> InputSet:
        """The file's lamps (paths relative to it) and its ``estimate:`` block's settings; where
        the estimate goes checked first.

        Raises
        ------
        calib.core.errors.InputError
            An invalid inputs file (its line and field named); earlier results without
            ``force``; an output directory that cannot be written.
        """
        file = Path(path)
        destination = out_dir if out_dir is not None else file.with_name(f"{file.stem}-estimate")
        check_out_dir(destination, force)
        contents = read_estimate_inputs(file)
        return InputSet(
            name=self.default_out_name(file),
            lamps=contents.lamps,
            out_dir=destination,
            notes=contents.notes,
            settings=contents.settings,
            settings_source=str(file),
        )


#: The reader of inputs files (the ``spectral_rig.inputs`` entry point ``inputs``).
INPUTS_FILES = InputsFiles()
