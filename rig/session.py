"""A session is a directory: an append-only ``log.jsonl`` plus the files it acknowledges.

::

    <session>/
      log.jsonl            one JSON record per line (rig.records), flushed and synced per record
      frames/<lamp>/       RAW files exactly as downloaded: scene-000.dng, dark-003.dng, …
      spectra/<lamp>/      spectra as CSV (calib.core.spectra.write_csv): warmup-002.csv, reference-000.csv
      transcripts/         every device exchange, one JSONL file per device role
      .reserve             room for the run's last records, while a run is active

Writing (:class:`SessionWriter`): a file is written under a temporary name, hashed (sha256) while
it is read for syncing, synced, renamed into place, its directory synced, and only then acknowledged
by a ``file`` record. Each record is one ``write`` of one line followed by one ``fdatasync``. Every
path is checked on the way (:mod:`drivers.local_files`): nothing is written through a link or
special file planted in the session. A write that fails part-way (a full disk) is cut back off, so
log and transcripts end with whole records; the writer then refuses further records except the
run's last ones, written in the room reserved for them (decision 0016).

Reading (:func:`read_session`): every record is validated; a torn last line (a crash mid-write) is
reported, not fatal; paths are never trusted — they must be plain relative names inside the data
directories, and a file is opened only if no component of its path is a symlink.
"""

from __future__ import annotations

import base64
import contextlib
import errno
import hashlib
import json
import os
import stat
import threading
import uuid
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args

from pydantic import TypeAdapter, ValidationError

from calib.core.checksums import CHUNK_BYTES, FileDigest, file_digest, file_sha256
from calib.core.spectra import Spectrum, write_csv
from drivers.base import TranscriptDirection, TranscriptEntry, TranscriptSink
from drivers.local_files import (
    UnsafeLocalPath,
    checked_directory,
    create_new_file,
    describe_entry,
    entries_below,
    is_plain,
    write_all,
)
from rig.errors import SessionFormatError, SessionWriteError, first_validation_problem
from rig.records import (
    DATA_DIRS,
    FRAMES_DIR,
    LOG_NAME,
    TRANSCRIPTS_DIR,
    AnyRecord,
    DiscardRecord,
    FileRecord,
    Record,
    StartRecord,
    StepRecord,
    StopRecord,
    check_session_path,
)

RecordT = TypeVar("RecordT", bound=Record)
TRANSCRIPT_DIRECTIONS = frozenset(get_args(TranscriptDirection))
SessionStatus = Literal["complete", "interrupted", "failed"]
Guard = Callable[[], AbstractContextManager[object]]

_RECORD_ADAPTER: TypeAdapter[AnyRecord] = TypeAdapter(AnyRecord)


def _sync(fd: int) -> None:
    """Make a file's data durable (``fdatasync`` where the OS has it)."""
    if hasattr(os, "fdatasync"):
        os.fdatasync(fd)
    else:  # pragma: no cover - macOS, Windows
        os.fsync(fd)


def _sync_directory(path: Path) -> None:
    """Make a rename or creation inside ``path`` durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover - Windows
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def move_tail_aside(path: Path, keep_bytes: int) -> str:
    """Copy ``path``'s bytes after the first ``keep_bytes`` to ``<name>.torn-<n>`` next to it
    (synced), then cut them off ``path``; return the copy's name.

    A torn last line (a crash mid-write) is kept for a person to look at, never silently dropped,
    and the file again ends with whole records.
    """
    number = 1
    while os.path.lexists(path.parent / f"{path.name}.torn-{number}"):
        number += 1
    aside = path.parent / f"{path.name}.torn-{number}"
    fd = os.open(path, os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        os.lseek(fd, keep_bytes, os.SEEK_SET)
        tail = b""
        while chunk := os.read(fd, CHUNK_BYTES):
            tail += chunk
        copy = create_new_file(aside)
        try:
            write_all(copy, tail)
            os.fsync(copy)
        finally:
            os.close(copy)
        _sync_directory(path.parent)
        os.ftruncate(fd, keep_bytes)
        os.fsync(fd)
    finally:
        os.close(fd)
    return aside.name


def new_session_name(now: datetime, session_id: str) -> str:
    """``20251121T122800Z-3fa9c2``: sortable by start time, unique by id."""
    return f"{now.astimezone(UTC):%Y%m%dT%H%M%SZ}-{session_id[:6]}"


# ------------------------------------------------------------------------------------ transcripts


def encode_transcript_entry(entry: TranscriptEntry) -> dict[str, object]:
    """A transcript entry as JSON: bytes as hex (``tx``/``rx``), text as UTF-8 or else base64."""
    payload = entry.payload
    if entry.direction in ("tx", "rx"):
        encoding, data = "hex", payload.hex()
    else:
        try:
            encoding, data = "utf-8", payload.decode("utf-8")
        except UnicodeDecodeError:
            encoding, data = "base64", base64.b64encode(payload).decode("ascii")
    return {
        "t_s": entry.monotonic_s,
        "device": entry.device,
        "dir": entry.direction,
        "enc": encoding,
        "data": data,
    }


def decode_transcript_line(line: str) -> TranscriptEntry:
    """Inverse of :func:`encode_transcript_entry` for one JSONL line."""
    item = json.loads(line)
    data = str(item["data"])
    match item["enc"]:
        case "hex":
            payload = bytes.fromhex(data)
        case "utf-8":
            payload = data.encode("utf-8")
        case "base64":
            payload = base64.b64decode(data, validate=True)
        case other:
            raise ValueError(f"unknown transcript encoding {other!r}")
    return TranscriptEntry(str(item["device"]), item["dir"], payload, float(item["t_s"]))


def parse_transcript(data: bytes, where: str) -> list[TranscriptEntry]:
    """The entries of a transcript file's bytes (JSONL, :func:`encode_transcript_entry`).

    Raises
    ------
    SessionFormatError
        For the first line that is not UTF-8 or not a transcript entry (``where`` names the file).
    """
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SessionFormatError(
            f"{where} is not UTF-8 ({exc.reason} at byte {exc.start})"
        ) from None
    entries = []
    for number, line in enumerate(text.split("\n"), start=1):
        if not line:
            continue
        try:
            entry = decode_transcript_line(line)
        except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as exc:
            raise SessionFormatError(
                f"{where} line {number} is not a transcript entry ({exc!r})"
            ) from None
        if not isinstance(entry.direction, str) or entry.direction not in TRANSCRIPT_DIRECTIONS:
            raise SessionFormatError(f"{where} line {number} has no valid direction")
        entries.append(entry)
    return entries


class TranscriptFile:
    """A :class:`drivers.base.TranscriptSink` appending to ``transcripts/<role>.jsonl``.

    Thread-safe (drivers run in worker threads). Each entry is one ``write`` of one line (no
    user-space buffer to lose); :meth:`sync` makes everything written so far durable; the sha256 is
    kept up to date while writing.

    Appends are atomic per entry: a write that fails part-way (a full disk) is cut back off the file,
    so the file always ends with a whole entry and matches its size and sha256. A failure never
    reaches the driver that recorded the entry (switching the lamps off must not fail because its
    exchange cannot be written down): the transcript stops taking entries, and :meth:`sync` — which
    runs before every step record — raises it, so no step is acknowledged whose exchanges are not
    all written.
    """

    def __init__(self, path: Path, relative: str) -> None:
        self.path = path
        self.relative = relative
        self._fd = create_new_file(path)
        os.close(self._fd)
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC)
        self._hash = hashlib.sha256()
        self._size = 0
        self._dirty = False
        self._lock = threading.Lock()
        self._closed = False
        self.failed: OSError | None = None
        """Why the transcript stopped taking entries (a write failed), or ``None``."""

    def record(self, entry: TranscriptEntry) -> None:
        line = (json.dumps(encode_transcript_entry(entry), ensure_ascii=False) + "\n").encode()
        with self._lock:
            if self._closed or self.failed is not None:
                return
            try:
                write_all(self._fd, line)
            except OSError as exc:
                self.failed = exc
                with contextlib.suppress(OSError):  # cut the partial entry back off
                    os.ftruncate(self._fd, self._size)
                return
            self._hash.update(line)
            self._size += len(line)
            self._dirty = True

    def sync(self) -> None:
        """Make the entries written so far durable (only if anything was written since).

        Raises
        ------
        OSError
            An entry could not be written (see :attr:`failed`), or the sync failed.
        """
        with self._lock:
            if self.failed is not None:
                raise OSError(
                    self.failed.errno, f"appending to {self.relative}: {self.failed.strerror}"
                )
            if self._dirty and not self._closed:
                _sync(self._fd)
                self._dirty = False

    def close(self) -> tuple[int, str]:
        """Sync and close; return the file's size and sha256 (of the entries it holds)."""
        with self._lock:
            if not self._closed:
                self._closed = True
                try:
                    if self._dirty:
                        _sync(self._fd)
                finally:
                    os.close(self._fd)
            return self._size, self._hash.hexdigest()


class PendingTranscripts:
    """Transcript sinks for devices opened before their session exists (a
    :data:`rig.station.TranscriptFactory`).

    A capture opens every device before it creates the session directory, so a device that cannot
    be opened leaves no session behind; what the devices exchanged meanwhile is kept in memory and
    written to the session's transcripts, in order, by :meth:`attach`.
    """

    def __init__(self) -> None:
        self._sinks: dict[str, _PendingSink] = {}

    def __call__(self, role: str) -> TranscriptSink:
        return self._sinks.setdefault(role, _PendingSink())

    def attach(self, writer: SessionWriter) -> None:
        """From now on every entry goes to ``writer``'s transcripts, the kept ones first."""
        for role, sink in self._sinks.items():
            sink.attach(writer.transcript_sink(role))


class _PendingSink:
    def __init__(self) -> None:
        self._kept: list[TranscriptEntry] = []
        self._target: TranscriptSink | None = None
        self._lock = threading.Lock()

    def record(self, entry: TranscriptEntry) -> None:
        with self._lock:
            if self._target is None:
                self._kept.append(entry)
                return
        self._target.record(entry)

    def attach(self, target: TranscriptSink) -> None:
        with self._lock:
            for entry in self._kept:
                target.record(entry)
            self._kept.clear()
            self._target = target


# ----------------------------------------------------------------------------------------- writer

#: A hidden file at the session's top holding disk space for the run's last records: released
#: when the run ends, so a full disk still gets its stop record (why, and whether the lamps are
#: off). Removed with the other leftovers when a killed run is resumed.
RESERVE_NAME = ".reserve"
RESERVE_BYTES = 64 * 1024
#: Longest message and traceback a stop record carries (the record is written on a full disk).
STOP_TEXT_CHARS = 2000
INCOMING_PREFIX = ".incoming-"
"""Temporary names of downloads and spectra before they are acknowledged (``.incoming-<run>-<n>.part``;
the camera driver's own temporary for it is ``..incoming-<run>-<n>.part.partial``)."""


class SessionWriter:
    """Creates a session directory and appends to it; the only code that writes a session.

    Every path it writes is checked on the way (:mod:`drivers.local_files`): directories are real
    directories inside the session, temporaries are created new (``O_EXCL | O_NOFOLLOW``), and a
    symbolic link or special file planted in the way is refused (:class:`SessionFormatError`
    naming it) rather than written through.

    Parameters
    ----------
    path
        The session directory (created; must not exist).
    guard
        Context manager factory wrapped around every log write and file commit, so an interrupt
        cannot tear them (the runner passes its deferred-interrupt section).
    """

    def __init__(self, path: Path, *, session_id: str | None = None, guard: Guard | None = None):
        self._init_state(path, session_id or uuid.uuid4().hex, guard, run=1, seq=0)
        try:
            path.mkdir(parents=False, exist_ok=False)
            for name in DATA_DIRS:
                (path / name).mkdir()
            os.close(create_new_file(path / LOG_NAME))
            self._open_log()
            self._reserve_room()
            _sync_directory(path)
            _sync_directory(path.parent)
        except FileExistsError:
            raise SessionWriteError(f"session directory {path} already exists") from None
        except OSError as exc:
            self.close()
            raise SessionWriteError(f"cannot create session directory {path}: {exc}") from exc

    def _init_state(
        self, path: Path, session_id: str, guard: Guard | None, *, run: int, seq: int
    ) -> None:
        """Every attribute, for a new session (:meth:`__init__`) and a continued one
        (:meth:`append`); the caller opens the log."""
        self.path = path
        self.session_id = session_id
        self.guard: Guard = guard or contextlib.nullcontext
        self.run = run
        self._seq = seq
        self._seq_at_start = seq
        self._broken: str | None = None
        self._log_intact = True
        self._finishing = False
        self._killed = False
        self._transcripts: dict[str, TranscriptFile] = {}
        self._incoming = 0
        self.torn_moved_to: str | None = None
        self._log_fd: int | None = None
        self._log_size = 0
        self.record_limit: int | None = None
        """After this many records of this run the writer stops as a killed process would
        (:meth:`kill`): replay uses it to end a run where the recorded one was killed."""
        self.on_kill: Callable[[], None] | None = None

    def _open_log(self) -> None:
        fd = os.open(self.path / LOG_NAME, os.O_WRONLY | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC)
        self._log_fd = fd
        self._log_size = os.fstat(fd).st_size

    def _reserve_room(self) -> None:
        fd = create_new_file(self.path / RESERVE_NAME, 0o600)
        try:
            os.posix_fallocate(fd, 0, RESERVE_BYTES)
        except OSError:
            os.close(fd)
            with contextlib.suppress(OSError):
                (self.path / RESERVE_NAME).unlink()
            raise
        os.close(fd)

    def _release_room(self) -> None:
        with contextlib.suppress(OSError):
            (self.path / RESERVE_NAME).unlink()

    @classmethod
    def append(cls, session: Session, *, guard: Guard | None = None) -> SessionWriter:
        """Continue ``session`` in a new run (resume): records go on from its last ``seq``.

        A torn last line is first moved aside to ``log.torn-<n>`` (copied, synced, then cut off the
        log): the only change ever made to existing log bytes. :attr:`torn_moved_to` names the copy.
        The session's leftovers must have been removed first (:func:`remove_leftovers`).

        Raises
        ------
        SessionWriteError
            When the log cannot be opened, the torn line cannot be moved aside, or there is no room
            for the run's last records.
        """
        start = session.start
        if start is None:
            raise SessionWriteError(f"{session.path}: the log has no start record to continue")
        writer = cls.__new__(cls)
        writer._init_state(
            session.path,
            start.session_id,
            guard,
            run=session.records[-1].run + 1,
            seq=len(session.records),
        )
        log = session.path / LOG_NAME
        try:
            if session.torn is not None:
                writer.torn_moved_to = move_tail_aside(log, log.lstat().st_size - session.torn.size)
            writer._open_log()
            writer._reserve_room()
        except OSError as exc:
            writer.close()
            raise SessionWriteError(
                f"cannot continue the session in {session.path}: {exc}"
            ) from exc
        return writer

    @classmethod
    def create(cls, parent: Path, *, guard: Guard | None = None) -> SessionWriter:
        """A new session in ``parent`` (created if needed), named by start time and id."""
        session_id = uuid.uuid4().hex
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SessionWriteError(f"cannot create output directory {parent}: {exc}") from exc
        name = new_session_name(datetime.now(UTC), session_id)
        return cls(parent / name, session_id=session_id, guard=guard)

    @property
    def records_written(self) -> int:
        return self._seq

    @property
    def broken(self) -> str | None:
        """Why the writer refuses to write, after a failed write; ``None`` while healthy."""
        return self._broken

    def _fail(self, what: str, exc: OSError) -> SessionWriteError:
        self._broken = self._broken or f"{what}: {exc}"
        return SessionWriteError(f"cannot write the session in {self.path}: {what}: {exc}")

    def refusal(self, exc: UnsafeLocalPath) -> SessionFormatError:
        """The error for a path planted in the session's way (named, relative to the session)."""
        shown = exc.path.relative_to(self.path) if exc.path.is_relative_to(self.path) else exc.path
        return SessionFormatError(
            f"{self.path}: {shown} is {exc.problem}, planted in the session; refused (nothing "
            "was written through it)"
        )

    def write(self, record_type: type[RecordT], **fields: Any) -> RecordT:
        """Append one record (``seq`` and ``run`` filled in), flushed and synced before returning.

        A write that fails part-way is cut back off the log (which then still ends with a whole
        record), and the writer refuses further records — except the run's last ones, after
        :meth:`finish`.
        """
        if self._killed:
            raise SessionWriteError(f"{self.path}: the run was stopped here (replayed kill)")
        if self._broken is not None and not (self._finishing and self._log_intact):
            raise SessionWriteError(f"{self.path}: an earlier write failed ({self._broken})")
        if self._log_fd is None:
            raise SessionWriteError(f"{self.path}: the session is closed")
        record = record_type(seq=self._seq, run=self.run, **fields)
        line = (record.model_dump_json() + "\n").encode("utf-8")
        log_fd = self._log_fd
        with self.guard():
            try:
                write_all(log_fd, line)
                _sync(log_fd)
            except OSError as exc:
                self._cut_back(log_fd)
                raise self._fail(f"appending to {LOG_NAME}", exc) from exc
            self._seq += 1
            self._log_size += len(line)
        if self.record_limit is not None and self._seq - self._seq_at_start >= self.record_limit:
            self.kill()
        return record

    def _cut_back(self, log_fd: int) -> None:
        """Cut a partly written record back off the log (if that fails too, the log is torn)."""
        try:
            os.ftruncate(log_fd, self._log_size)
            _sync(log_fd)
        except OSError:
            self._log_intact = False

    def finish(self) -> bool:
        """The run is ending: release the room reserved for its last records.

        Returns whether they can be written: after a failed write only if the log was cut back to
        whole records (a full disk), never after :meth:`kill`.
        """
        self._release_room()
        self._finishing = True
        return not self._killed and self._log_intact and self._log_fd is not None

    @property
    def killed(self) -> bool:
        """Whether :meth:`kill` stopped the writer."""
        return self._killed

    def kill(self) -> None:
        """Stop writing as a killed process stops: nothing more, not even the last records."""
        self._killed = True
        self._broken = self._broken or "the run was stopped here (replayed kill)"
        if self.on_kill is not None:
            self.on_kill()

    def transcript_sink(self, role: str) -> TranscriptFile:
        """The transcript file for a device role (``spectrometer``, ``camera``, ``relays``)."""
        if role not in self._transcripts:
            # A resumed run keeps the earlier runs' transcripts and starts its own.
            relative = transcript_path(role, self.run)
            try:
                self._transcripts[role] = TranscriptFile(self.path / relative, relative)
            except UnsafeLocalPath as exc:
                raise self.refusal(exc) from None
            except OSError as exc:
                raise self._fail(f"creating {relative}", exc) from exc
        return self._transcripts[role]

    def sync_transcripts(self) -> None:
        """Make every transcript entry so far durable (before a step record acknowledges it)."""
        for transcript in self._transcripts.values():
            try:
                transcript.sync()
            except OSError as exc:
                raise self._fail(f"syncing {transcript.relative}", exc) from exc

    def incoming_path(self, directory: str = FRAMES_DIR) -> Path:
        """A fresh temporary path in a data directory for a download (never acknowledged as is).

        The leading dot keeps it out of what a file record may name. The directory is checked to
        be the session's own; the name (and the camera driver's temporary for it) must be free.

        Raises
        ------
        SessionFormatError
            Something was planted under that name or in the way.
        """
        self._incoming += 1
        name = f"{INCOMING_PREFIX}{self.run}-{self._incoming:05d}.part"
        try:
            parent = checked_directory(self.path, directory)
        except UnsafeLocalPath as exc:
            raise self.refusal(exc) from None
        except OSError as exc:
            raise self._fail(f"creating {directory}", exc) from exc
        for taken in (parent / name, parent / f".{name}.partial"):
            if os.path.lexists(taken):
                raise self.refusal(UnsafeLocalPath(taken, describe_entry(taken)))
        return parent / name

    def _free_name(self, relative: str) -> str:
        """``relative``, or ``stem.2.ext``, ``stem.3.ext``… if taken (acknowledged files are never
        replaced). A name taken by anything but a regular file is refused (planted)."""
        candidate = relative
        stem, dot, suffix = relative.rpartition(".")
        if not dot or "/" in suffix:
            stem, suffix = relative, ""
        number = 1
        while os.path.lexists(self.path / candidate):
            if not stat.S_ISREG((self.path / candidate).lstat().st_mode):
                raise UnsafeLocalPath(self.path / candidate, describe_entry(self.path / candidate))
            number += 1
            candidate = f"{stem}.{number}" + (f".{suffix}" if suffix else "")
        return candidate

    def final_name(self, relative: str) -> str:
        """The name :meth:`commit_file` would acknowledge ``relative`` under now.

        Raises
        ------
        SessionFormatError
            The name, or one after it, is taken by a planted link or special file.
        """
        try:
            return self._free_name(check_session_path(relative))
        except UnsafeLocalPath as exc:
            raise self.refusal(exc) from None

    def commit_file(
        self,
        temporary: Path,
        relative: str,
        *,
        key: str,
        role: Literal["frame", "dark", "spectrum"],
        units: str | None = None,
        bandwidth_nm: float | None = None,
        known: FileDigest | None = None,
    ) -> FileRecord:
        """Sync ``temporary``, rename it to ``relative`` and acknowledge it with a ``file`` record.

        The file is read once, for the sha256, through the descriptor that is then synced; with
        ``known`` (its digest taken by the caller) it is not read again unless its state changed
        since (:func:`calib.core.checksums.file_digest`). Returns the record (its ``path`` may
        carry a ``.2`` suffix when ``relative`` was already taken).

        Raises
        ------
        SessionFormatError
            A directory on the way or the final name is a planted link or special file.
        SessionWriteError
            The disk is full or failing.
        """
        if self._killed:  # a killed process renames nothing more either (a replayed kill)
            raise SessionWriteError(f"{self.path}: the run was stopped here (replayed kill)")
        directory, _, _ = check_session_path(relative).rpartition("/")
        with self.guard():
            try:
                checked_directory(self.path, directory)
                relative = self._free_name(relative)
                final = self.path / relative
                if not stat.S_ISREG(temporary.lstat().st_mode):
                    raise UnsafeLocalPath(temporary, describe_entry(temporary))
                digest = file_digest(temporary, sync=True, known=known)
                temporary.replace(final)
                _sync_directory(final.parent)
            except UnsafeLocalPath as exc:
                raise self.refusal(exc) from None
            except OSError as exc:
                if exc.errno == errno.ELOOP:  # the temporary became a link
                    raise self.refusal(UnsafeLocalPath(temporary, "a symbolic link")) from None
                raise self._fail(f"storing {relative}", exc) from exc
        return self.write(
            FileRecord,
            key=key,
            role=role,
            path=relative,
            size=digest.size,
            sha256=digest.sha256,
            units=units,
            bandwidth_nm=bandwidth_nm,
        )

    def write_spectrum(
        self,
        relative: str,
        spectrum: Spectrum,
        *,
        key: str,
        units: str,
        bandwidth_nm: float | None = None,
    ) -> FileRecord:
        """Store a spectrum as CSV (``wavelength_nm,value``) and acknowledge it.

        ``units`` of ``value`` and the instrument's ``bandwidth_nm`` go into the file record and the
        CSV's ``# units:``/``# bandwidth_nm:`` header lines (so ``calib estimate`` reads them too).
        """
        temporary = self.stage_spectrum(relative, spectrum, units=units, bandwidth_nm=bandwidth_nm)
        return self.commit_file(
            temporary, relative, key=key, role="spectrum", units=units, bandwidth_nm=bandwidth_nm
        )

    def stage_spectrum(
        self, relative: str, spectrum: Spectrum, *, units: str, bandwidth_nm: float | None = None
    ) -> Path:
        """Write a spectrum's CSV (as :meth:`write_spectrum`) to a new temporary, not yet synced
        nor acknowledged: :meth:`commit_file` does that (under ``relative``)."""
        temporary = self.incoming_path(relative.split("/")[0])
        try:
            os.close(create_new_file(temporary))  # new and ours: write_csv cannot be led astray
            write_csv(temporary, spectrum, header={"units": units, "bandwidth_nm": bandwidth_nm})
        except UnsafeLocalPath as exc:
            raise self.refusal(exc) from None
        except OSError as exc:
            with contextlib.suppress(OSError):
                temporary.unlink()
            raise self._fail(f"writing {relative}", exc) from exc
        return temporary

    def close_transcripts(self) -> None:
        """Close the transcripts, acknowledging each with a ``file`` record (before the stop record).

        A transcript that stopped taking entries (a write failed) is acknowledged as it is: whole
        entries up to the failure.
        """
        for role, transcript in self._transcripts.items():
            try:
                size, sha256 = transcript.close()
            except OSError as exc:
                self._broken = self._broken or f"closing {transcript.relative}: {exc}"
                continue
            self.write(
                FileRecord,
                key=f"transcripts/{role}",
                role="transcript",
                path=transcript.relative,
                size=size,
                sha256=sha256,
            )

    def close(self) -> None:
        """Close any transcript still open (without records) and the log, and give back the room
        reserved for the last records; safe to call twice."""
        for transcript in self._transcripts.values():
            with contextlib.suppress(OSError):
                transcript.close()
        if self._log_fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._log_fd)
            self._log_fd = None
        if not self._killed:
            self._release_room()


def transcript_path(role: str, run: int) -> str:
    """``transcripts/<role>.jsonl`` for run 1, ``transcripts/<role>.run<n>.jsonl`` for later runs."""
    name = role if run == 1 else f"{role}.run{run}"
    return check_session_path(f"{TRANSCRIPTS_DIR}/{name}.jsonl")


# ----------------------------------------------------------------------------------------- reader


@dataclass(frozen=True)
class TornLine:
    """The incomplete last line of a log (a crash mid-write): where, and how many bytes."""

    line: int
    size: int


@dataclass(frozen=True)
class FileProblem:
    """An acknowledged file that is missing, unsafe, or differs from its record."""

    path: str
    problem: str

    def __str__(self) -> str:
        return f"{self.path}: {self.problem}"


@dataclass
class Session:
    """A session as read from disk: validated records, the torn tail if any, and derived views."""

    path: Path
    records: list[Record] = field(default_factory=list)
    torn: TornLine | None = None

    @property
    def start(self) -> StartRecord | None:
        """The first run's start record."""
        first = self.records[0] if self.records else None
        return first if isinstance(first, StartRecord) else None

    @property
    def stop(self) -> StopRecord | None:
        """The last run's stop record, if it has one."""
        for record in reversed(self.records):
            if isinstance(record, StartRecord):
                return None
            if isinstance(record, StopRecord):
                return record
        return None

    @property
    def status(self) -> SessionStatus:
        """``complete``, ``failed``, or ``interrupted`` (stopped by a signal, or no stop record)."""
        stop = self.stop
        if stop is None or stop.exit_status == "abort":
            return "interrupted"
        return "complete" if stop.exit_status == "success" else "failed"

    def done_steps(self) -> dict[str, StepRecord]:
        """The last ``done`` record of every step key."""
        return {r.key: r for r in self.records if isinstance(r, StepRecord) and r.status == "done"}

    def discarded(self) -> list[DiscardRecord]:
        """Files the log acknowledged and later set aside (stale readings, files that failed to verify)."""
        return [r for r in self.records if isinstance(r, DiscardRecord)]

    def files(self) -> list[FileRecord]:
        """Every acknowledged file that was not discarded afterwards."""
        discarded = {r.path: r.seq for r in self.discarded()}
        return [
            r
            for r in self.records
            if isinstance(r, FileRecord) and discarded.get(r.path, -1) < r.seq
        ]

    @property
    def resumable(self) -> bool:
        """Whether ``rig resume`` continues it: it has a start record and did not complete."""
        return self.start is not None and self.status != "complete"

    def file_path(self, relative: str) -> Path:
        """The on-disk path of a session-relative file, refusing anything that could leave the session.

        Raises
        ------
        SessionFormatError
            When the path is not a safe relative name, or any component is a symlink or missing, or
            the file is not a regular file.
        """
        found = self._locate(relative)
        if isinstance(found, _Unreadable):
            raise SessionFormatError(f"{self.path}: {found.message}")
        return found

    def _locate(self, relative: str) -> Path | _Unreadable:
        """:meth:`file_path`'s answer: the path, or why the file cannot be read."""
        try:
            check_session_path(relative)
        except ValueError as exc:
            return _Unreadable(str(exc), str(exc))
        current = self.path
        for part in relative.split("/"):
            current = current / part
            try:
                mode = current.lstat().st_mode
            except FileNotFoundError:
                return _Unreadable.of(relative, "does not exist")
            if stat.S_ISLNK(mode):
                return _Unreadable.of(relative, f"goes through a symlink ({current.name}); refused")
        if not stat.S_ISREG(current.lstat().st_mode):
            return _Unreadable.of(relative, "is not a regular file")
        return current

    def verify_files(self) -> list[FileProblem]:
        """Check every acknowledged file's size and sha256; return the problems (empty when all verify)."""
        problems = []
        for record in self.files():
            found = self._locate(record.path)
            problem = found.problem if isinstance(found, _Unreadable) else _differs(found, record)
            if problem is not None:
                problems.append(FileProblem(record.path, problem))
        return problems

    def file_problem(self, record: FileRecord) -> str | None:
        """How an acknowledged file differs from its log record (size first, then sha256), or
        ``None`` when it verifies; a :class:`SessionFormatError` when it is not a regular file
        inside the session."""
        return _differs(self.file_path(record.path), record)


@dataclass(frozen=True)
class _Unreadable:
    """Why a session file cannot be read: ``problem`` as a :class:`FileProblem` says it (the path
    named apart), ``message`` as an error says it (the path in it)."""

    problem: str
    message: str

    @classmethod
    def of(cls, relative: str, problem: str) -> _Unreadable:
        return cls(problem, f"{relative} {problem}")


def _differs(path: Path, record: FileRecord) -> str | None:
    """How the file at ``path`` differs from its log record (size first, then sha256), or ``None``."""
    size, sha256 = file_sha256(path)
    if size != record.size:
        return f"{size} bytes, the log says {record.size}"
    if sha256 != record.sha256:
        return "sha256 differs from the log"
    return None


def _is_leftover(name: str) -> bool:
    """A temporary name of the writer or the camera driver (never acknowledged)."""
    return name.startswith((INCOMING_PREFIX, f".{INCOMING_PREFIX}"))


def check_before_writing(session: Session) -> list[Path]:
    """Check a session's directories before anything is written into it; return the leftovers.

    The data directories must be real directories, and nothing in them may be a symbolic link or a
    special file: a link planted there (a lamp directory pointing elsewhere, a temporary name
    pointing at a file to overwrite) is refused, named, before any device is opened. Leftovers are
    the temporaries a killed run left (``.incoming-*``, the camera's ``..incoming-*.partial``, the
    ``.reserve`` file) and any frame or spectrum no ``file`` record acknowledges (a run killed, or
    stopped by a full disk, between renaming it into place and writing its record), to be removed
    by :func:`remove_leftovers` when the session is continued. The log alone then decides what the
    new run finds on disk, so the names it gives its files (``stem.2.ext`` when ``stem.ext`` is
    taken) do not depend on where in a store the previous run stopped: a replay gives the same.

    Raises
    ------
    SessionFormatError
        A data directory is not a directory, or something in them is a link or special file.
    """
    leftovers: list[Path] = []
    acknowledged = {
        session.path / record.path for record in session.records if isinstance(record, FileRecord)
    }
    reserve = session.path / RESERVE_NAME
    if os.path.lexists(reserve):
        if not stat.S_ISREG(reserve.lstat().st_mode):
            raise _planted(session, reserve)
        leftovers.append(reserve)
    for name in DATA_DIRS:
        top = session.path / name
        if not os.path.lexists(top):
            continue
        if not stat.S_ISDIR(top.lstat().st_mode):
            raise _planted(session, top)
        for entry in entries_below(top):
            path = Path(entry.path)
            if not is_plain(entry):
                raise _planted(session, path)
            if entry.is_file(follow_symlinks=False) and (
                _is_leftover(entry.name) or (name != TRANSCRIPTS_DIR and path not in acknowledged)
            ):
                # A killed run's transcripts are acknowledged by the resume itself, not here.
                leftovers.append(path)
    return sorted(leftovers)


def _planted(session: Session, path: Path) -> SessionFormatError:
    return SessionFormatError(
        f"{session.path}: {path.relative_to(session.path)} is {describe_entry(path)}; a session "
        "holds only plain files and directories, so nothing is written into it: remove it (a "
        "frame or spectrum it stood for is then taken again)"
    )


def remove_leftovers(leftovers: list[Path]) -> None:
    """Remove the temporaries :func:`check_before_writing` found (never following a link)."""
    for leftover in leftovers:
        leftover.unlink(missing_ok=True)


def _validate_sequence(records: list[Record], log: Path) -> None:
    for index, record in enumerate(records):
        if record.seq != index:
            raise SessionFormatError(
                f"{log}: line {index + 1} has seq {record.seq}, expected {index} "
                "(records lost, reordered or duplicated)"
            )
    if records and not isinstance(records[0], StartRecord):
        raise SessionFormatError(
            f"{log}: line 1 is a {type(records[0]).__name__}, not a start record"
        )
    run = 0
    for index, record in enumerate(records):
        if isinstance(record, StartRecord):
            if record.run != run + 1:
                raise SessionFormatError(
                    f"{log}: line {index + 1} starts run {record.run}, expected {run + 1}"
                )
            run = record.run
        elif record.run != run:
            raise SessionFormatError(
                f"{log}: line {index + 1} belongs to run {record.run} inside run {run}"
            )


def read_session(path: str | Path) -> Session:
    """Read and validate a session directory's log.

    Raises
    ------
    SessionFormatError
        When ``path`` is not a session (no regular ``log.jsonl``), or a complete line is not a valid
        record, or the records are out of sequence. A torn *last* line is reported in
        :attr:`Session.torn` instead.
    """
    directory = Path(path)
    log = directory / LOG_NAME
    try:
        mode = log.lstat().st_mode
    except FileNotFoundError:
        raise SessionFormatError(f"{directory}: not a session (no {LOG_NAME})") from None
    if not stat.S_ISREG(mode):
        raise SessionFormatError(f"{log}: not a regular file")
    data = log.read_bytes()
    lines = data.split(b"\n")
    tail = lines.pop()  # empty when the log ends with a newline
    session = Session(directory)
    for number, raw in enumerate(lines, start=1):
        session.records.append(_parse_line(raw, number, log))
    if tail:
        session.torn = TornLine(len(lines) + 1, len(tail))
    _validate_sequence(session.records, log)
    return session


def _parse_line(raw: bytes, number: int, log: Path) -> Record:
    try:
        record = _RECORD_ADAPTER.validate_json(raw)
    except ValidationError as exc:
        problem = first_validation_problem(exc.errors(), "record")
        raise SessionFormatError(f"{log}: line {number}: {problem}") from None
    assert isinstance(record, Record)
    return record


@dataclass(frozen=True)
class SessionSummary:
    """One line of ``rig sessions``; ``resumable`` is :attr:`Session.resumable` (never for an
    invalid session)."""

    path: Path
    status: SessionStatus | Literal["invalid"]
    started: datetime | None = None
    plan: str | None = None
    frames: int = 0
    reason: str = ""
    resumable: bool = False


def summarise(path: Path) -> SessionSummary:
    """A session's status and headline numbers; ``invalid`` (with the reason) when it cannot be read."""
    try:
        session = read_session(path)
    except (SessionFormatError, OSError) as exc:
        return SessionSummary(path, "invalid", reason=str(exc))
    start = session.start
    stop = session.stop
    frames = sum(1 for f in session.files() if f.role in ("frame", "dark"))
    reason = stop.reason if stop is not None else "no stop record (crashed or killed)"
    if session.torn is not None:
        reason += f"; torn last line {session.torn.line}"
    runs = session.records[-1].run if session.records else 0
    if runs > 1:
        reason += f" (run {runs})"
    return SessionSummary(
        path,
        session.status,
        start.wall_time if start else None,
        start.plan.name if start else None,
        frames,
        reason,
        session.resumable,
    )


def find_sessions(parent: Path) -> Iterator[Path]:
    """Session directories directly inside ``parent`` (those with a ``log.jsonl``), by name."""
    if not parent.is_dir():
        return
    for child in sorted(parent.iterdir()):
        if child.is_dir() and not child.is_symlink() and (child / LOG_NAME).exists():
            yield child
