"""The person at the bench: manual actions a plan asks for, when no driver can do them.

The rig's drivers have no rotation stage, so aiming the spectrometer at the grating's beams
(:class:`rig.steps.AimSpectrometer`) is a manual action: the runner hands it to the station's
:class:`Operator` and waits until it is done. An operator is as small a protocol as the devices:

* :class:`ConsoleOperator` (real hardware): prints the instruction and waits for Enter on the
  terminal; ``q`` (or the end of input) declines, and the run stops as failed (``operator_declined``),
  resumable once the bench is put right. A first Ctrl-C or SIGTERM during the wait stops the run
  after it, as between steps. Without a terminal it refuses at once (``operator_unavailable``),
  naming what to do — never a run that hangs on a pipe.
* the twin's hands (:func:`rig.twin.station_of`): the simulated bench turns its spectrometer.
* :class:`ScriptedOperator` (tests): does what it is told and records it.
* replay (:mod:`rig.replay`): the recording says it was done; nothing to do again.

A rotation stage would be a fourth operator: a driver that turns to ``angle_deg``.
"""

from __future__ import annotations

import select
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, TextIO

from rig.errors import RigError

#: How often the console operator checks for a stop request while waiting (s).
POLL_S = 0.25


@dataclass(frozen=True)
class ManualAction:
    """What a person is asked to do.

    Attributes
    ----------
    key
        The step asking (its session key).
    instruction
        The action in words.
    beam
        Where the spectrometer is to look (:data:`rig.steps.SpectrometerBeam`).
    angle_deg
        The turn from the 0th-order beam (the 1st order only).
    centre_nm
        The 1st-order wavelength to put in the middle of the field (the 1st order only).
    """

    key: str
    instruction: str
    beam: str
    angle_deg: float = 0.0
    centre_nm: float | None = None


StopCheck = Callable[[], bool]
"""True once a stop was requested (the operator then gives up waiting)."""


class Operator(Protocol):
    """Whoever does the plan's manual actions."""

    def perform(self, action: ManualAction, stop_requested: StopCheck) -> bool:
        """Have ``action`` done; ``False`` when a stop request ended the wait first.

        Raises
        ------
        OperatorDeclined
            The operator refused.
        OperatorUnavailable
            Nobody can be asked.
        """
        ...


class OperatorDeclined(RigError):
    """The operator declined a manual action: the run stops, resumable."""

    reason = "operator_declined"


class OperatorUnavailable(RigError):
    """A manual action is needed and nobody can be asked (no terminal)."""

    reason = "operator_unavailable"
    exit_code = 2


class ConsoleOperator:
    """A person at the terminal: the instruction is printed, Enter confirms, ``q`` declines.

    Parameters
    ----------
    reader, writer
        The terminal (standard input and error by default).
    """

    def __init__(self, reader: TextIO | None = None, writer: TextIO | None = None) -> None:
        self.reader = reader if reader is not None else sys.stdin
        self.writer = writer if writer is not None else sys.stderr

    def perform(self, action: ManualAction, stop_requested: StopCheck) -> bool:
        if not self.reader.isatty():
            raise OperatorUnavailable(
                f"{action.key}: a person must {action.instruction}, but the rig runs without a "
                "terminal to ask on; run rig capture (or rig resume) in a terminal, or set "
                "measure_grating to null"
            )
        self.writer.write(
            f"\nOPERATOR — {action.key}:\n  {action.instruction}.\n"
            "  Press Enter when done (q then Enter to stop the run; it can be resumed).\n"
        )
        self.writer.flush()
        while not stop_requested():
            ready, _, _ = select.select([self.reader], [], [], POLL_S)
            if not ready:
                continue
            line = self.reader.readline()
            if line == "" or line.strip().lower() in ("q", "quit", "stop"):
                raise OperatorDeclined(
                    f"{action.key}: the operator declined to {action.instruction}; resume the "
                    "session with rig resume when the bench is ready"
                )
            return True
        return False


@dataclass
class ScriptedOperator:
    """An operator that does every action at once (declining those keyed in ``decline``),
    recording each; ``act`` is called with the action (the twin's hands turn its spectrometer)."""

    act: Callable[[ManualAction], None] | None = None
    decline: frozenset[str] = frozenset()
    done: list[ManualAction] = field(default_factory=list)

    def perform(self, action: ManualAction, stop_requested: StopCheck) -> bool:
        if action.key in self.decline:
            raise OperatorDeclined(f"{action.key}: the operator declined")
        if self.act is not None:
            self.act(action)
        self.done.append(action)
        return True
