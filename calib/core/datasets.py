"""Measured camera sensitivities: readers for every collection, lookup, and a pinned download.

Collections (the layout of a data directory; ``--data-dir`` may point at any such directory):

``solomatov-akkaynak-2023/``
    Solomatov & Akkaynak (2023) ground truths: ``data/ground-truths/*.csv`` (48) and
    ``data/ground-truths/test-data/*.csv`` (1), CSV ``wavelength,red,green,blue`` at 400–700/10 nm.
    Makabe et al. (2025) split these 49 into 44 training and 5 test cameras
    (:data:`MAKABE2025_TEST_FILES`, :func:`makabe2025_split`). Their *predicted* curves
    (``data/predictions/``, estimates, not measurements) are read as a separate collection when
    present but are not part of the pinned download.
``jiang-2013-camspec/``
    Jiang et al. (2013) ``data/camspec_database.txt``: a camera-name line followed by R, G, B lines of
    33 tab-separated values (400–720/10 nm), after a few header lines.
``butcherg-ssf-data/``
    Glenn Butcher's CSVs (``#`` comment header with ``#Camera:``, rows ``wl,r,g,b``).
``rawtoaces/``
    AMPAS rawtoaces camera JSON (spectral-data schema 0.1.0): ``spectral_data.data.main["<nm>"]``.
``rawtoaces-data/``
    The Academy's rawtoaces-data collection (52 cameras, ``data/camera/*.json``, schema 0.1.0 or
    1.0.0 with the same ``spectral_data.data.main``; Apache-2.0), and its ``data/aliases.json``
    (:func:`calib.core.camera_bodies.read_rawtoaces_aliases`). The copy bundled with spectral-rig
    (:data:`calib.core.formats.ampas.RAWTOACES_DATA`) is read when the data directory has none.
``colour-science`` (built in, no files)
    ``colour.MSDS_CAMERA_SENSITIVITIES`` and the rawtoaces Canon EOS 5D Mark II CSV inside the
    colour package.

Every camera is normalised so that its maximum over all channels is 1.

The data directory is looked up in this order: the ``data_dir`` argument (``--data-dir``), the
environment variable ``SPECTRAL_RIG_DATA``, then ``<user cache dir>/camera_sensitivities`` (see
:func:`default_data_dir`), where :func:`fetch_datasets` puts the files. None of these files is
redistributed with spectral-rig: the download takes each from its public repository at a pinned commit
and checks its SHA-256.
"""

from __future__ import annotations

import os
import re
import urllib.parse
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import platformdirs

from calib.core.camera_bodies import BodyIndex, default_body_index, names_camera
from calib.core.checksums import file_sha256
from calib.core.colour_data import camera_sensitivities, rawtoaces_sensitivity_path
from calib.core.errors import CalibError, InputError, SpectrumError
from calib.core.formats.ampas import RAWTOACES_DATA as BUNDLED_RAWTOACES_DATA
from calib.core.formats.ampas import read_camera_json
from calib.core.formats.rgb_csv import read_camera_csv
from calib.core.spectra import MultiSpectrum

#: Environment variable naming a data directory.
DATA_DIR_ENV = "SPECTRAL_RIG_DATA"

SOLOMATOV = "solomatov-akkaynak-2023"
SOLOMATOV_PREDICTIONS = "solomatov-akkaynak-2023-predictions"
CAMSPEC = "jiang-2013-camspec"
BUTCHERG = "butcherg-ssf-data"
RAWTOACES = "rawtoaces"
RAWTOACES_DATA = "rawtoaces-data"
COLOUR_SCIENCE = "colour-science"

#: Every collection name :func:`load_collection` accepts.
COLLECTIONS: tuple[str, ...] = (
    SOLOMATOV,
    SOLOMATOV_PREDICTIONS,
    CAMSPEC,
    BUTCHERG,
    RAWTOACES,
    RAWTOACES_DATA,
    COLOUR_SCIENCE,
)

#: The collections of the default basis, in priority order: each one present adds only the bodies
#: the ones before it lack, one record per body (:func:`reference_cameras`). Solomatov & Akkaynak
#: alone: adding rawtoaces-data's other bodies made the validation cameras' estimates slightly worse
#: (decision 0027, bench/basis_choice.py).
REFERENCE_COLLECTIONS: tuple[str, ...] = (SOLOMATOV,)

#: The five test cameras of Makabe et al. (2025) §4.1 (the other 44 ground truths train the basis).
MAKABE2025_TEST_FILES: tuple[str, ...] = (
    "Canon_600D_Jiang-et-al-2013.csv",
    "iPhone_12-Pro-Max_Tominaga_etal_2021.csv",
    "Olympus_EPL2_Jiang-et-al-2013.csv",
    "Pentax_K5_Jiang-et-al-2013.csv",
    "Samsung_Galaxy-S20_Tominaga_etal_2021.csv",
)

DEFAULT_BASE_URL = "https://raw.githubusercontent.com"

FETCH_HINT = "run `rig data fetch` (or `calib data fetch`) to download it, or pass --data-dir DIR"


class DatasetFetchError(CalibError):
    """Some pinned files could not be downloaded or failed their SHA-256 check."""

    def __init__(self, message: str, failures: Sequence[tuple[str, str]]) -> None:
        self.failures = list(failures)
        super().__init__(message)


@dataclass(frozen=True, eq=False)
class CameraRecord:
    """One camera's measured sensitivity.

    Attributes
    ----------
    name
        Camera and measurement source, e.g. ``"Canon 600D (Jiang-et-al-2013)"``.
    camera
        The camera alone, e.g. ``"Canon 600D"``.
    collection
        One of :data:`COLLECTIONS`.
    sensitivity
        R, G, B curves, maximum over all channels = 1.
    source
        Where it was read from (a path relative to the data directory, or a colour-science key).
    """

    name: str
    camera: str
    collection: str
    sensitivity: MultiSpectrum
    source: str


def _normalised(curves: MultiSpectrum, name: str) -> MultiSpectrum:
    normalised = curves.normalised()
    return MultiSpectrum(normalised.wavelength_nm, normalised.values, ("r", "g", "b"), name=name)


# ------------------------------------------------------------------------------ directory lookup


def default_data_dir() -> Path:
    """``<platformdirs.user_cache_dir("spectral-rig")>/camera_sensitivities``."""
    return Path(platformdirs.user_cache_dir("spectral-rig")) / "camera_sensitivities"


def resolve_data_dir(data_dir: str | Path | None = None) -> Path:
    """The data directory: ``data_dir``, else ``$SPECTRAL_RIG_DATA``, else :func:`default_data_dir`.

    Raises
    ------
    InputError
        When an explicitly given directory does not exist, or none of the three holds any collection,
        with the fix (fetch, or ``--data-dir``).
    """
    if data_dir is not None:
        path = Path(data_dir).expanduser()
        if not path.is_dir():
            raise InputError(f"data directory does not exist; {FETCH_HINT}", source=str(path))
        return path
    env = os.environ.get(DATA_DIR_ENV)
    if env:
        path = Path(env).expanduser()
        if not path.is_dir():
            raise InputError(
                f"${DATA_DIR_ENV} names a directory that does not exist; {FETCH_HINT}",
                source=str(path),
            )
        return path
    path = default_data_dir()
    if not path.is_dir():
        raise InputError(
            f"no reference camera data: not given with --data-dir, ${DATA_DIR_ENV} is unset, and "
            f"{path} does not exist; {FETCH_HINT}",
            source="camera data",
        )
    return path


def _collection_dir(data_dir: str | Path | None, collection: str) -> Path:
    if collection == RAWTOACES_DATA:
        # Bundled with spectral-rig (Apache-2.0); a data directory's own copy wins.
        try:
            local = resolve_data_dir(data_dir) / RAWTOACES_DATA
        except InputError:
            return BUNDLED_RAWTOACES_DATA
        return local if local.is_dir() else BUNDLED_RAWTOACES_DATA
    root = resolve_data_dir(data_dir)
    folder = root / (SOLOMATOV if collection == SOLOMATOV_PREDICTIONS else collection)
    if not folder.is_dir():
        raise InputError(
            f"collection {collection} is missing from the data directory {root}; {FETCH_HINT}",
            source=str(folder),
        )
    return folder


# ------------------------------------------------------------------------------------- readers

_SOLOMATOV_NAME = re.compile(
    r"^(?P<camera>.+?)_(?P<source>[A-Z][A-Za-z]+(?:-et-al|_etal)?[-_]\d{4})$"
)


def read_rgb_csv(
    path: str | Path, *, name: str | None = None, channels_in_order: bool = False
) -> MultiSpectrum:
    """Read a camera CSV by column name (``wavelength,red,green,blue`` in any order), normalised.

    Used for the Solomatov/Akkaynak files and the colour-science rawtoaces CSV; butcherg's CSVs have
    no header line and are read with ``channels_in_order=True`` (their documented ``wl,r,g,b``).
    """
    path = Path(path)
    label = name or path.stem
    curves = read_camera_csv(path, name=label, channels_in_order=channels_in_order)
    return _normalised(curves.to_multispectrum(), label)


def solomatov_camera_name(path: str | Path) -> tuple[str, str]:
    """``("Canon 600D", "Jiang-et-al-2013")`` from ``Canon_600D_Jiang-et-al-2013.csv``."""
    stem = Path(path).stem
    if stem.startswith("predicted-"):
        return stem.removeprefix("predicted-").replace(
            "-", " ", 1
        ), "Solomatov-Akkaynak-2023 prediction"
    match = _SOLOMATOV_NAME.match(stem)
    if match is None:
        return stem.replace("_", " "), "unknown"
    return match["camera"].replace("_", " "), match["source"]


def read_camspec_txt(path: str | Path) -> list[CameraRecord]:
    """Read Jiang et al.'s ``camspec_database.txt`` (400–720 nm, 10 nm): a name line, then R, G, B.

    Header lines before the first camera are skipped (a camera starts at the first non-numeric line
    followed by three numeric lines).
    """
    path = Path(path)
    try:
        lines = [
            line.strip() for line in path.read_text(encoding="utf-8", errors="replace").splitlines()
        ]
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", source=str(path)) from None

    def numeric(line: str) -> list[float] | None:
        try:
            values = [float(token) for token in line.split()]
        except ValueError:
            return None
        return values or None

    wavelength = np.arange(400.0, 721.0, 10.0)
    records: list[CameraRecord] = []
    index = 0
    while index < len(lines):
        rows = [numeric(line) for line in lines[index + 1 : index + 4]]
        if numeric(lines[index]) is None and lines[index] and len(rows) == 3 and all(rows):
            camera = lines[index]
            values = np.array(rows, dtype=np.float64).T
            if values.shape != (wavelength.size, 3):
                raise SpectrumError(
                    f"camera {camera!r}: expected 3 rows of {wavelength.size} values, got "
                    f"{[len(r or []) for r in rows]}",
                    source=f"{path} line {index + 1}",
                )
            curves = MultiSpectrum(wavelength, values, name=camera, negative="clip")
            records.append(
                CameraRecord(
                    f"{camera} (camspec)", camera, CAMSPEC, _normalised(curves, camera), str(path)
                )
            )
            index += 4
        else:
            index += 1
    if not records:
        raise SpectrumError(
            "no camera blocks found (name line + 3 numeric lines)", source=str(path)
        )
    return records


def butcherg_camera_name(path: str | Path) -> str:
    """The ``#Camera:`` header of a butcherg CSV (falls back to the file name)."""
    path = Path(path)
    try:
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines()[:10]:
            if line.lower().startswith("#camera:"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return path.stem.replace("_", " ")


def read_rawtoaces_json(path: str | Path) -> MultiSpectrum:
    """Read an AMPAS spectral-data JSON camera file (:func:`calib.core.formats.ampas.read_camera_json`)."""
    curves = read_camera_json(path).curves
    return _normalised(curves.to_multispectrum(), curves.name)


def colour_science_cameras() -> list[CameraRecord]:
    """The cameras inside colour-science: two NPL measurements and the rawtoaces Canon 5D Mk II."""
    records = [
        CameraRecord(
            key,
            key.split(" (")[0],
            COLOUR_SCIENCE,
            _normalised(curves, key),
            f"colour.MSDS_CAMERA_SENSITIVITIES[{key!r}]",
        )
        for key, curves in camera_sensitivities().items()
    ]
    canon = rawtoaces_sensitivity_path("CANON_EOS_5DMark_II_RGB_Sensitivities.csv")
    if canon.is_file():
        name = "Canon EOS 5D Mark II (rawtoaces)"
        records.append(
            CameraRecord(
                name,
                "Canon EOS 5D Mark II",
                COLOUR_SCIENCE,
                read_rgb_csv(canon, name=name),
                str(canon),
            )
        )
    return records


def _relative(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


def load_collection(collection: str, data_dir: str | Path | None = None) -> list[CameraRecord]:
    """All cameras of one collection, sorted by name.

    Parameters
    ----------
    collection
        One of :data:`COLLECTIONS`.
    data_dir
        The data directory (see :func:`resolve_data_dir`); unused for ``"colour-science"``.
    """
    if collection == COLOUR_SCIENCE:
        return colour_science_cameras()
    if collection not in COLLECTIONS:
        raise InputError(
            f"unknown collection {collection}; choose from {', '.join(COLLECTIONS)}",
            source="collection",
        )
    folder = _collection_dir(data_dir, collection)
    root = folder.parent
    records: list[CameraRecord] = []
    if collection == SOLOMATOV:
        files = sorted((folder / "data" / "ground-truths").rglob("*.csv"))
    elif collection == SOLOMATOV_PREDICTIONS:
        files = sorted((folder / "data" / "predictions").glob("predicted-*.csv"))
    elif collection == CAMSPEC:
        return read_camspec_txt(folder / "data" / "camspec_database.txt")
    elif collection == BUTCHERG:
        files = sorted(folder.rglob("*.csv"))
    else:
        files = sorted((folder / "data" / "camera").glob("*.json"))
    for path in files:
        relative = _relative(path, root)
        if collection in (SOLOMATOV, SOLOMATOV_PREDICTIONS):
            camera, reference = solomatov_camera_name(path)
            name = f"{camera} ({reference})"
            curves = read_rgb_csv(path, name=name)
        elif collection == BUTCHERG:
            camera = butcherg_camera_name(path)
            kind = "spectroscope" if "spectroscope" in path.parts else "camspec"
            name = f"{camera} (butcherg {kind})"
            curves = read_rgb_csv(path, name=name, channels_in_order=True)
        else:
            curves = read_rawtoaces_json(path)
            camera = curves.name
            name = f"{camera} ({collection})"
        records.append(CameraRecord(name, camera, collection, curves, relative))
    if not records:
        raise InputError(
            f"collection {collection} has no camera files; {FETCH_HINT}", source=str(folder)
        )
    return records


def makabe2025_split(
    data_dir: str | Path | None = None,
) -> tuple[list[CameraRecord], list[CameraRecord]]:
    """The 44 training and 5 test cameras of Makabe et al. (2025) §4.1 (Solomatov/Akkaynak data)."""
    records = load_collection(SOLOMATOV, data_dir)
    test_names = set(MAKABE2025_TEST_FILES)
    test = [r for r in records if Path(r.source).name in test_names]
    train = [r for r in records if Path(r.source).name not in test_names]
    if len(test) != len(MAKABE2025_TEST_FILES):
        found = {Path(r.source).name for r in test}
        raise InputError(
            f"test cameras missing from {SOLOMATOV}: {sorted(test_names - found)}; {FETCH_HINT}",
            source=SOLOMATOV,
        )
    return train, test


def find_camera(records: Sequence[CameraRecord], query: str) -> CameraRecord:
    """The one record whose name contains ``query`` (case- and punctuation-insensitive)."""

    def key(text: str) -> str:
        return re.sub(r"[^a-z0-9]", "", text.lower())

    wanted = key(query)
    exact = [r for r in records if key(r.name) == wanted or key(r.camera) == wanted]
    matches = exact or [r for r in records if wanted in key(r.name)]
    if len(matches) != 1:
        names = ", ".join(r.name for r in (matches or records)[:12])
        what = "no camera" if not matches else f"{len(matches)} cameras"
        raise InputError(f"{what} match {query!r}; candidates: {names}", source="camera")
    return matches[0]


# ------------------------------------------------------------------------ the basis' cameras


def exclude_cameras(
    records: Sequence[CameraRecord], patterns: Sequence[str], index: BodyIndex | None = None
) -> tuple[list[CameraRecord], list[CameraRecord]]:
    """``(kept, excluded)``: the records no pattern names, and those some pattern names
    (:func:`calib.core.camera_bodies.names_camera`: the same body, or a shell wildcard)."""
    kept: list[CameraRecord] = []
    excluded: list[CameraRecord] = []
    for record in records:
        named = any(
            names_camera(pattern, record.camera, index) or names_camera(pattern, record.name, index)
            for pattern in patterns
        )
        (excluded if named else kept).append(record)
    return kept, excluded


def new_bodies(
    records: Sequence[CameraRecord],
    known: Sequence[CameraRecord],
    index: BodyIndex | None = None,
) -> list[CameraRecord]:
    """The ``records`` whose body is not among ``known``'s, one record per body (the first):
    what a collection adds to another, each body once (one body, one weight)."""
    index = index or default_body_index()
    seen = {index.body(record.camera) for record in known}
    added: list[CameraRecord] = []
    for record in records:
        body = index.body(record.camera)
        if body not in seen:
            seen.add(body)
            added.append(record)
    return added


@dataclass(frozen=True)
class ReferenceCameras:
    """The measured cameras a default camera basis is built from.

    Attributes
    ----------
    records
        The cameras.
    source
        Where they come from, for the result's record.
    fallback
        Why these are not the default collection and what to fetch, when they are not; ``None``
        when they are.
    """

    records: tuple[CameraRecord, ...]
    source: str
    fallback: str | None = None


#: Why the bundled rawtoaces-data cameras are a fallback, and what to do about it.
FALLBACK_BASIS = (
    "the camera basis comes from the {n} rawtoaces-data cameras bundled with spectral-rig "
    "({where}), not the Solomatov & Akkaynak (2023) ground truths: where the lamps leave the camera open the "
    "estimate is less accurate (decision 0027); fetch them with `calib data fetch --collection "
    + SOLOMATOV
    + "` (or `rig data fetch`), or give --data-dir DIR"
)


def reference_cameras(
    data_dir: str | Path | None = None, collections: Sequence[str] = REFERENCE_COLLECTIONS
) -> ReferenceCameras:
    """The cameras of the default basis (:func:`calib.model.bases.default_camera_basis`).

    ``collections`` in priority order, each one present in the data directory adding only the
    bodies the ones before it lack (:func:`new_bodies`: make and model, market names and aliases
    joined). Without the Solomatov & Akkaynak ground truths the rawtoaces-data cameras come first
    (the data directory's copy, else the one bundled with spectral-rig), the other collections
    present de-duplicated against them, and :attr:`ReferenceCameras.fallback` says so.

    Parameters
    ----------
    data_dir
        The camera data directory (:func:`resolve_data_dir`); ``None`` and none found: the bundled
        rawtoaces-data alone.
    collections
        Names of :data:`COLLECTIONS` (default :data:`REFERENCE_COLLECTIONS`);
        ``(SOLOMATOV, RAWTOACES_DATA)`` adds rawtoaces-data's other bodies to the ground truths.

    Raises
    ------
    InputError
        A data directory named (``data_dir`` or ``$SPECTRAL_RIG_DATA``) that does not exist; an
        unknown collection.
    """
    unknown = [name for name in collections if name not in COLLECTIONS]
    if unknown:
        raise InputError(
            f"unknown collection {', '.join(unknown)}; choose from {', '.join(COLLECTIONS)}",
            source="collections",
        )
    try:
        root: Path | None = resolve_data_dir(data_dir)
    except InputError:
        if data_dir is not None or os.environ.get(DATA_DIR_ENV):
            raise
        root = None

    def present(name: str) -> bool:
        if name in (RAWTOACES_DATA, COLOUR_SCIENCE):
            return True  # bundled, built in
        folder = SOLOMATOV if name == SOLOMATOV_PREDICTIONS else name
        return root is not None and (root / folder).is_dir()

    fallback: str | None = None
    order = [name for name in collections if present(name)]
    if SOLOMATOV not in order:
        order = [RAWTOACES_DATA, *(name for name in order if name != RAWTOACES_DATA)]
    records: list[CameraRecord] = []
    parts: list[str] = []
    for name in order:
        loaded = load_collection(name, root)
        # The first collection whole (a body measured twice keeps both curves, as in the paper).
        added = new_bodies(loaded, records) if records else loaded
        if name == RAWTOACES_DATA:
            folder = _collection_dir(root, RAWTOACES_DATA)
            where = "bundled" if folder == BUNDLED_RAWTOACES_DATA else f"from {folder}"
        else:
            where = ""
        label = f"{name} {'ground truths' if name == SOLOMATOV else 'cameras'}"
        if records:
            parts.append(f"{name} bodies not among them ({len(added)})")
        else:
            parts.append(f"{label} ({len(added)}{', ' + where if where else ''})")
            if name != SOLOMATOV:
                reason = "no data directory" if root is None else f"no {SOLOMATOV} in {root}"
                fallback = FALLBACK_BASIS.format(n=len(added), where=reason)
        records.extend(added)
    return ReferenceCameras(tuple(records), " + ".join(parts), fallback)


# ------------------------------------------------------------------------------ pinned download


@dataclass(frozen=True)
class PinnedFile:
    """One file of a collection, pinned to a commit of its public repository."""

    collection: str
    repository: str
    commit: str
    source_path: str
    sha256: str
    size_bytes: int

    @property
    def local_path(self) -> str:
        """Path inside the data directory (the collection folder + the repository's own path)."""
        return f"{self.collection}/{self.source_path}"

    def url(self, base_url: str = DEFAULT_BASE_URL) -> str:
        quoted = urllib.parse.quote(self.source_path, safe="/")
        return f"{base_url.rstrip('/')}/{self.repository}/{self.commit}/{quoted}"


@dataclass
class FetchReport:
    """What :func:`fetch_datasets` did, file by file (paths inside ``destination``)."""

    destination: Path
    downloaded: list[str] = field(default_factory=list)
    already_present: list[str] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)


ProgressCallback = Callable[[int, int, str], None]

_PINNED_SOURCES: dict[str, tuple[str, str, tuple[tuple[str, str, int], ...]]] = {}


def pinned_files(collections: Sequence[str] | None = None) -> list[PinnedFile]:
    """The pinned files of the given collections (default: all downloadable ones)."""
    names = list(collections) if collections is not None else list(_PINNED_SOURCES)
    unknown = [name for name in names if name not in _PINNED_SOURCES]
    if unknown:
        raise InputError(
            f"cannot fetch {', '.join(unknown)}; downloadable collections are "
            f"{', '.join(_PINNED_SOURCES)} ({RAWTOACES_DATA} is bundled)",
            source="collections",
        )
    return [
        PinnedFile(name, repository, commit, path, sha256, size)
        for name in names
        for repository, commit, files in [_PINNED_SOURCES[name]]
        for path, sha256, size in files
    ]


def _file_is_valid(path: Path, pinned: PinnedFile) -> bool:
    try:
        if path.stat().st_size != pinned.size_bytes:
            return False
        return file_sha256(path) == (pinned.size_bytes, pinned.sha256)
    except OSError:
        return False


class DatasetSourceUnreachable(DatasetFetchError):
    """The download host could not be reached at all (offline, a name that does not resolve, a
    connection refused): raised at the first file, not after trying every one."""


#: Retries of a file whose download broke off or arrived corrupted (pooch waits 1 s, then 2 s).
DEFAULT_RETRIES = 2
#: Seconds to wait for the server to accept a connection (a silent network fails in this time).
CONNECT_TIMEOUT_S = 5.0


class _Downloader:
    """pooch's downloader for one fetch: HTTP(S) through :class:`pooch.HTTPDownloader`, file:// as a
    copy. A host that cannot be reached raises :class:`DatasetSourceUnreachable`, which pooch does
    not retry; a 4xx answer is not retried either (it will not change)."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s

    def __call__(self, url: str, output_file: str, pooch_object: object) -> None:
        parsed = urllib.parse.urlsplit(url)
        if parsed.scheme == "file":
            import shutil
            from urllib.request import url2pathname

            shutil.copyfile(url2pathname(parsed.path), output_file)
            return
        import pooch
        import requests

        download = pooch.HTTPDownloader(
            timeout=(min(CONNECT_TIMEOUT_S, self.timeout_s), self.timeout_s),
            headers={"User-Agent": "spectral-rig data fetch"},
        )
        try:
            download(url, output_file, pooch_object)
        except requests.exceptions.ConnectTimeout as exc:
            raise _unreachable(parsed.netloc, "no answer in time") from exc
        except requests.exceptions.ConnectionError as exc:
            reason = _connection_failure(exc)
            if reason is None:
                raise  # broke off after connecting: pooch retries
            raise _unreachable(parsed.netloc, reason) from exc
        except requests.exceptions.HTTPError as exc:
            status = exc.response.status_code if exc.response is not None else 0
            if 400 <= status < 500:
                raise _NotRetried(f"HTTP {status}") from exc
            raise


class _NotRetried(Exception):
    """A failure pooch must not retry (it is neither a ValueError nor a requests error)."""


def _connection_failure(exc: Exception) -> str | None:
    """Why no connection could be made (a name that does not resolve, refused, unreachable), or
    ``None`` when the connection was made and broke off."""
    import urllib3.exceptions

    reason = getattr(exc.args[0] if exc.args else None, "reason", None)
    if isinstance(reason, urllib3.exceptions.NameResolutionError):
        return "its name does not resolve"
    if isinstance(reason, urllib3.exceptions.NewConnectionError):
        text = str(reason).lower()
        return "connection refused" if "refused" in text else "no route to it"
    return None


def _unreachable(host: str, reason: str) -> DatasetSourceUnreachable:
    return DatasetSourceUnreachable(
        f"cannot reach {host} ({reason}; offline?): nothing downloaded. Run the fetch again when "
        "online, or give --base-url URL (a mirror) or --data-dir DIR (the collections already on "
        "disk); until then the basis is the bundled rawtoaces-data cameras",
        [],
    )


def _checksum_failure(exc: ValueError) -> str:
    text = str(exc)
    return "checksum mismatch" + (
        " (the file differs from the pinned SHA-256)" if "hash" in text.lower() else f": {text}"
    )


def fetch_datasets(
    destination: str | Path | None = None,
    *,
    collections: Sequence[str] | None = None,
    base_url: str | None = None,
    progress: ProgressCallback | None = None,
    timeout_s: float = 30.0,
    retries: int = DEFAULT_RETRIES,
) -> FetchReport:
    """Download the pinned camera collections through pooch, verifying every file's SHA-256.

    Files already present and valid are skipped (the data directory is pooch's cache); pooch
    downloads each file to a temporary name, checks its hash and only then moves it into place, so
    an interrupted or corrupted download never leaves a file under the final name. A download that
    breaks off or arrives corrupted is retried (``retries``); a host that cannot be reached stops
    the fetch at the first file with one line (:class:`DatasetSourceUnreachable`).

    Parameters
    ----------
    destination
        The data directory to fill (default :func:`default_data_dir`).
    collections
        Which collections (default: every downloadable one; see :func:`pinned_files`).
    base_url
        Mirror root: a file's URL is ``{base_url}/{repository}/{commit}/{path}``
        (default ``https://raw.githubusercontent.com``; ``file://`` URLs work too, never retried).
    progress
        Called as ``progress(done, total, local_path)`` after each file.
    timeout_s
        Per-request timeout (connecting: at most :data:`CONNECT_TIMEOUT_S`).
    retries
        Further attempts at a file whose download failed after connecting.

    Returns
    -------
    FetchReport

    Raises
    ------
    DatasetSourceUnreachable
        The host could not be reached (at the first file).
    DatasetFetchError
        After trying every file, when any failed (HTTP error or checksum mismatch). Valid files
        are kept, so re-running fetches only the rest.
    """
    # Deferred: pooch and requests load only to download.
    import pooch

    root = Path(destination).expanduser() if destination is not None else default_data_dir()
    files = pinned_files(collections)
    base = base_url or DEFAULT_BASE_URL
    fetcher = pooch.create(
        path=root,
        base_url="",
        registry={pinned.local_path: f"sha256:{pinned.sha256}" for pinned in files},
        urls={pinned.local_path: pinned.url(base) for pinned in files},
        retry_if_failed=0 if base.startswith("file:") else retries,
    )
    downloader = _Downloader(timeout_s)
    report = FetchReport(destination=root)
    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel("WARNING")  # pooch says each download on stderr; the progress bar does
    try:
        for done, pinned in enumerate(files, start=1):
            if _file_is_valid(root / pinned.local_path, pinned):
                report.already_present.append(pinned.local_path)
            else:
                try:
                    fetcher.fetch(pinned.local_path, downloader=downloader)
                    report.downloaded.append(pinned.local_path)
                except ValueError as exc:
                    report.failed.append((pinned.local_path, _checksum_failure(exc)))
                except (OSError, _NotRetried) as exc:  # requests' errors are OSErrors
                    reason = getattr(exc, "strerror", None) or one_line_reason(exc)
                    report.failed.append((pinned.local_path, f"{pinned.url(base)}: {reason}"))
            if progress is not None:
                progress(done, len(files), pinned.local_path)
    finally:
        logger.setLevel(level)
    if report.failed:
        path, why = report.failed[0]
        raise DatasetFetchError(
            f"{len(report.failed)} of {len(files)} files failed into {root}, the first {path} "
            f"({why}). Valid files are kept; run the fetch again to retry the rest.",
            report.failed,
        )
    return report


def one_line_reason(exc: BaseException) -> str:
    """An exception's message on one line, without the nested reprs requests puts in it."""
    text = " ".join(str(exc).split())
    return re.sub(r"\(Caused by .*\)$", "", text).strip() or type(exc).__name__


def collection_status(data_dir: str | Path | None = None) -> dict[str, tuple[int, int]]:
    """Per downloadable collection: ``(valid files present, pinned files)`` in the data directory."""
    try:
        root = resolve_data_dir(data_dir)
    except InputError:
        root = Path(data_dir) if data_dir is not None else default_data_dir()
    status: dict[str, tuple[int, int]] = {}
    for name in _PINNED_SOURCES:
        files = pinned_files([name])
        valid = sum(_file_is_valid(root / pinned.local_path, pinned) for pinned in files)
        status[name] = (valid, len(files))
    return status


# Pinned files: (path in the repository, sha256, size in bytes), from the collection's MANIFEST.tsv.
# The 1012 *predicted* curves of Solomatov & Akkaynak are estimates, not measurements, and are not
# pinned here; they are read when present (collection "solomatov-akkaynak-2023-predictions").
#: 32 files of butcherg/ssf-data at ae8620d680877716671c0f0772ef4e625eb9039c.
_FILES_BUTCHERG_SSF_DATA: tuple[tuple[str, str, int], ...] = (
    (
        "Canon/1DMarkIII/camspec/Canon_1DMarkIII.csv",
        "eaffb660bb825cf963390c530209f2022cd3ad13c3298bf730ee62473a14dda1",
        1327,
    ),
    (
        "Canon/20D/camspec/Canon_20D.csv",
        "6bbd5aec729407f1d7b1abb0d3a0d2d5ce046f5807934a6dcf81b78ff2fca77a",
        1302,
    ),
    (
        "Canon/300D/camspec/Canon_300D.csv",
        "0ce5105190988dfef5739c201d71001e971d019e0e2bbefa4b197cad6f7432a3",
        1306,
    ),
    (
        "Canon/40D/camspec/Canon_40D.csv",
        "03c35bb4611fe3df861e7ddaed64903686ecdf5eb9ed794ce18c82ab4e863217",
        1299,
    ),
    (
        "Canon/500D/camspec/Canon_500D.csv",
        "f1c79de4b7d0cb66a3a028d7447ef5645e0fe39c6aeaee729a83f0afcc49b96b",
        1276,
    ),
    (
        "Canon/50D/camspec/Canon_50D.csv",
        "177c67a255ff32ace77467754aaadf03eed8e61835ffa6e313ff8c7043799489",
        1281,
    ),
    (
        "Canon/5DMarkII/camspec/Canon_5DMarkII.csv",
        "a3c38660d9931cb920873661f0c270a61486c1c6b9d45f7b6d5c3a6cf9f40196",
        1110,
    ),
    (
        "Canon/600D/camspec/Canon_600D.csv",
        "4896ee7707212f56d27f0f0b46bd71b3dedade81806a31d47b100bd13ebabfb4",
        1296,
    ),
    (
        "Canon/60D/camspec/Canon_60D.csv",
        "f942fe7fda9b61a6823b819e7d47025a6bb66aec30ab687c7fef397c9f36e8da",
        1296,
    ),
    (
        "Hasselblad/H2/camspec/Hasselblad_H2.csv",
        "1a230169ed45bdc3083be7ef9752c8d9258849fe1821ddd1f431ed95d8522f02",
        1284,
    ),
    (
        "Nikon/D200/camspec/Nikon_D200.csv",
        "24ffbcdfbc4fc2ef7562e6f5362ba9ef74c1e5a11aaca575219e45d8763c13af",
        1318,
    ),
    (
        "Nikon/D3/camspec/Nikon_D3.csv",
        "304dad3bb604e350874256c6fcbba3f9125fff6f64fe1dca942265ffabaa78e1",
        1320,
    ),
    (
        "Nikon/D300s/camspec/Nikon_D300s.csv",
        "33fd09c8ddef0004a45e94dd041f1ad4ae4bb1b5495b6f716b180be4275f6970",
        1305,
    ),
    (
        "Nikon/D3500/spectroscope/Nikon_D3500_ssf.csv",
        "f8fdcf6911435489d48f43db438a7b454aa295ec089bf9f3b39e67b87e8f015f",
        1428,
    ),
    (
        "Nikon/D3X/camspec/Nikon_D3X.csv",
        "b0d8f8256af4746795c0f17db5189564c7ba166a3c1377fd1acaa19cc8ffb5ba",
        1311,
    ),
    (
        "Nikon/D40/camspec/Nikon_D40.csv",
        "87d95861b1ab6be13e191d0cb2c4a056424e9bdcb4543bc9977cd90a2249980d",
        1308,
    ),
    (
        "Nikon/D50/camspec/Nikon_D50.csv",
        "a56c9b5be09c2a8216dae62db2011b599abd47185bf5747fd0fcc98d31dffbc3",
        1304,
    ),
    (
        "Nikon/D50/spectroscope/Nikon_D50_ssf.csv",
        "6fae0dc8bf1867106d874911ffa6d6801e1797179b385604a1d38b3e87d4746f",
        1426,
    ),
    (
        "Nikon/D5100/camspec/Nikon_D5100.csv",
        "ce49cc79483fa5498447d9fb14741d7e750bfc3534a73b0303c19275569f66df",
        1305,
    ),
    (
        "Nikon/D700/camspec/Nikon_D700.csv",
        "d03350d72808b20debc62cb2cb4229b65c0a012afe5c892bcc5106286efa92e5",
        1317,
    ),
    (
        "Nikon/D7000/spectroscope/Nikon_D7000_ssf.csv",
        "c81c0d750338907789aae11f5d7138bdde6ede741c5a0b96f7e88cf8e885cfb8",
        1428,
    ),
    (
        "Nikon/D80/camspec/Nikon_D80.csv",
        "dbc27b763c4da9e77bd4d71f235f2693202ad3a5a60d9a29e3a4805e33a7f214",
        1334,
    ),
    (
        "Nikon/D90/camspec/Nikon_D90.csv",
        "9b363ab8293b3db3c3250ceb2098dc94aee67490a48a0c85429d2500d65d753e",
        1310,
    ),
    (
        "Nikon/Z6/spectroscope/Nikon_Z6_ssf.csv",
        "6cb4dc7b550acd6c3793f13b0a188145ccc3fcb2e50d559c4c37c06e181bb642",
        1426,
    ),
    (
        "Nokia/N900/camspec/Nokia_N900.csv",
        "98b97d7b75b3d1d18893b4a955c52c98516a47addc53491ee1ccc9875e2f0930",
        1281,
    ),
    (
        "Olympus/E-PL2/camspec/Olympus_E-PL2.csv",
        "7dded71cfb16ccdb9dd4a9de42318f45a659638ec8a885f8b2cbacd0620e28a5",
        1308,
    ),
    (
        "Pentax/K-5/camspec/Pentax_K-5.csv",
        "48ab73f61a7c30ce9f397a7c1a7fca76e2deea1f1a72ebdd69c9fe8364bbf447",
        1298,
    ),
    (
        "Pentax/Q/camspec/Pentax_Q.csv",
        "ff4c1ca9bbbdfedbea3e340da60d8bd7f10f1bf60d0b8c88088f2c8653ad0576",
        1277,
    ),
    (
        "Phase_One/[unspecified]/camspec/Phase_One.csv",
        "57db46d3a937620005d184943fc05afe4c18c9906a8a5c78e7b489fe95365f10",
        1294,
    ),
    (
        "Point_Grey/Grasshopper2_14S5C/camspec/Point_Grey_Grasshopper2_14S5C.csv",
        "35224f666957d5653f2bf22fd7c2530f67a91374c42e1817da0a7b7255368771",
        1298,
    ),
    (
        "Point_Grey/Grasshopper_50S5C/camspec/Point_Grey_Grasshopper_50S5C.csv",
        "760f6e3c6f5d1d54f3bc8f449f875f21ca32566409dabf97ebaff7c74da1a43e",
        1297,
    ),
    (
        "Sony/NEX-5N/camspec/SONY_NEX-5N.csv",
        "2c4deb3c2ceb5ce23cfc99a88f7e9c13ec530d4f940b4abb3caf07877b077fb1",
        1299,
    ),
)
#: 1 files of supersasha/difp-electron at 6735425e38108de69b412d5273472fa068d75eae.
_FILES_JIANG_2013_CAMSPEC: tuple[tuple[str, str, int], ...] = (
    (
        "data/camspec_database.txt",
        "067a7629d0836d0bc95f27b53f157ec0cf7e965beb66074426117c17fe1cda11",
        24619,
    ),
)
#: 11 files of AcademySoftwareFoundation/rawtoaces at 300324c09fcc8bf19ac5066100c85d1022589b48.
_FILES_RAWTOACES: tuple[tuple[str, str, int], ...] = (
    (
        "data/camera/arri_d21_380_780_5.json",
        "1b226b98ccbad7f57c3ba33401f61746d8420ebee742e6e8ae9ad65a4a667a8b",
        8259,
    ),
    (
        "data/camera/canon_eos_5d_mark_ii_380_780_5.json",
        "2f3896c59c834c7bd6c35f718b3c42abdcc90dfde7021c0a36789a6a437c88de",
        8362,
    ),
    (
        "data/camera/canon_powershot_s90_380_780_5.json",
        "0e6f9ac80d5762305908a7eea369d487753908b6ec0195aafaa9398b305bdadf",
        8360,
    ),
    (
        "data/camera/canon_xti_380_780_5.json",
        "125c49cc96aeb35be2fbb34de0414cf5191b2a004adc5519d89bbf645060d241",
        8340,
    ),
    (
        "data/camera/nikon_d200_380_780_5.json",
        "07051f16fe48c361818c88fe346742841f9ef39ecbff40b9f969316e31dd0d1f",
        8342,
    ),
    (
        "data/camera/nikon_d5100_380_780_5.json",
        "b6e434375b140d773fd419bbb2cef82eaee6295b694923a35041ab3fa74a4ed4",
        8339,
    ),
    (
        "data/camera/nikon_d7000_380_780_5.json",
        "4cfc6d81c45c00a0c17a3a3c7b9a11af26138acac4297392f3c698f20977d7f7",
        8344,
    ),
    (
        "data/camera/nikon_d700_380_780_5.json",
        "e085797376a9f1ca3b0f65dfb8f22ffaffcf1c939ea0dfbd752cb356af795801",
        8342,
    ),
    (
        "data/camera/nikon_d70_380_780_5.json",
        "5054220f502e6498c78f1216a63c22b660eacc308dd6683ebc035ca26454e5f4",
        8340,
    ),
    (
        "data/camera/sony_ilce-7rm2_380_780_5.json",
        "b61de7198c0a0453211e692d2df73fbdee7d8dc8321509b3538ba7643f2d5761",
        6732,
    ),
    (
        "data/camera/sony_ilce-7sm2_380_780_5.json",
        "1247226a418a4b24db1da748b0812293d53aa567f9970ea45485f1ab8f33158b",
        6732,
    ),
)
#: 50 files of COLOR-Lab-Eilat/Spectral-sensitivity-estimation at e9958089605676c27437ea98665490d40f104d5d.
_FILES_SOLOMATOV_AKKAYNAK_2023: tuple[tuple[str, str, int], ...] = (
    (
        "data/ground-truths/Canon_10D_Huynh-2007.csv",
        "ae0354e36c86f408e8c8b0a28c8970e280106b3b653edbb972fef88f13944a82",
        922,
    ),
    (
        "data/ground-truths/Canon_10D_Kawakami-et-al-2013.csv",
        "5f6c2df3031ecf4e230bbc217e03af5cba63fa04fa9245a20b492a48533f3685",
        1023,
    ),
    (
        "data/ground-truths/Canon_1D-Mk-III_Jiang-et-al-2013.csv",
        "0dcbc15414575341d31293674ae1e530293e6f3f6c2b87ec538e7ee2d8fecf11",
        1033,
    ),
    (
        "data/ground-truths/Canon_1Ds-Mk-II_Akkaynak-et-al-2011.csv",
        "ee34944e58583e75e1f336e92fcb6382aa63685fcb1bd72a4528235fc252caee",
        1030,
    ),
    (
        "data/ground-truths/Canon_1Ds-Mk-II_Brady-2009.csv",
        "e894e045c36254706bf6c0d2cc40084d4cec87b09bc73e6eebe12ca8b1fb2f88",
        978,
    ),
    (
        "data/ground-truths/Canon_20D_Jiang-et-al-2013.csv",
        "a90fcb3103c752607c9ee1c7316916cb445a44c1c6726921abc3a15152a79070",
        1021,
    ),
    (
        "data/ground-truths/Canon_300D_Jiang-et-al-2013.csv",
        "6988de798c66d38d490184a81b79dcd247e985bd34c2b3d3243693770f07fe17",
        1020,
    ),
    (
        "data/ground-truths/Canon_400D_Lebourgeois-2008.csv",
        "4f61cd9b21ea30b696991b015632687dee35361a8595a9a18fdb23bd1b468fb9",
        1024,
    ),
    (
        "data/ground-truths/Canon_40D_Jiang-et-al-2013.csv",
        "cfb1fbb9e2d900244844ce093bfc24a3916307f7a353c0c542922dc1ba8fcd2b",
        1018,
    ),
    (
        "data/ground-truths/Canon_40D_Mauer-2009.csv",
        "d62eeec30f900baf5495eca7a52c885db393c045c80dc39bc0fae61920eb2dde",
        658,
    ),
    (
        "data/ground-truths/Canon_500D_Jiang-et-al-2013.csv",
        "15f7dd488e4afcc4ea6c655a33c4b815f1ebf25c02abcb03e123ba6bbb60dc9b",
        992,
    ),
    (
        "data/ground-truths/Canon_50D_Jiang-et-al-2013.csv",
        "4f51db9abd6d68cce2eb90fd13fee327a0ffaf5cc340a14f328dd0eba8d1400c",
        999,
    ),
    (
        "data/ground-truths/Canon_5D-Mk-II_Jiang-et-al-2013.csv",
        "79a7dd176a626bcb78dd087aa4925d870f3ffc7d7d60b46b772800965a7b2837",
        846,
    ),
    (
        "data/ground-truths/Canon_5D-Mk-II_Kawakami-et-al-2013.csv",
        "4c3f241a52e761805546dac49ea8b41615725be8594cf9fa3c0a32ea70d38745",
        801,
    ),
    (
        "data/ground-truths/Canon_5D_Kawakami-et-al-2013.csv",
        "6a2e062a3fbab9ee63c645145ae39e7cc985267c11d0cb81b4b615eab0dfa1fd",
        787,
    ),
    (
        "data/ground-truths/Canon_600D_Jiang-et-al-2013.csv",
        "41618ea51ac52fbe4158aa76e268664993f3ddf99d7197ca893e31e0340b6430",
        1012,
    ),
    (
        "data/ground-truths/Canon_60D_Jiang-et-al-2013.csv",
        "2f81f1a1968b5a594953afe82fb8f68da8775ba4f2116594fb49c93de59361d1",
        1014,
    ),
    (
        "data/ground-truths/Leica_M8_Mauer-2009.csv",
        "6db864a7bc9d3e700f0fa5396f74f8119f33aa5ce366cf4af2bb8fa9564ae113",
        667,
    ),
    (
        "data/ground-truths/Nikon_D1x_Kawakami-et-al-2013.csv",
        "41d8a64687af2d9979a19918f6d8d21e2b21d4e82274d2e1c4385a080f523ff0",
        787,
    ),
    (
        "data/ground-truths/Nikon_D200_Jiang-et-al-2013.csv",
        "218a8a9a62a1ad13eeeebaf4b1eb4535f35f114674f65493f28c02709a68fd15",
        1030,
    ),
    (
        "data/ground-truths/Nikon_D200_Mauer-2009.csv",
        "e61e0ed282d14a32766c955f44435c9ed439077566e0de753c782712ed7ff994",
        651,
    ),
    (
        "data/ground-truths/Nikon_D300s_Jiang-et-al-2013.csv",
        "a12c3245d021970eaa8d6cdcaa6242b63c778529a40f9791a917543a38a794af",
        1022,
    ),
    (
        "data/ground-truths/Nikon_D3X_Jiang-et-al-2013.csv",
        "195d9e5bc23128e3a10beca513958aa9d9458ed9bcabc8c7a53998175de77dd2",
        1025,
    ),
    (
        "data/ground-truths/Nikon_D3_Brady-2009.csv",
        "9be322913a382695dc793a14630beeaf022911638aca6551cd666b6230bb1ad5",
        999,
    ),
    (
        "data/ground-truths/Nikon_D3_Jiang-et-al-2013.csv",
        "c89908eb72d213cfc54b9086b509685c529c0089c716977aaf0b7dd1cd792753",
        1035,
    ),
    (
        "data/ground-truths/Nikon_D40_Jiang-et-al-2013.csv",
        "459bee43e0f267ed3e2a3fac1e6cdfd944572a3d8d5ce2973aeeb2eca9ae887b",
        1030,
    ),
    (
        "data/ground-truths/Nikon_D50_Jiang-et-al-2013.csv",
        "2689cce7b9d4107dede0ff4c46a90100cdb3c8163ab63dd74683d5f721583c66",
        1028,
    ),
    (
        "data/ground-truths/Nikon_D5100_Jiang-et-al-2013.csv",
        "34e749509a73401fb5a6ebc0db6f62d83b6016abea1e7a729329096201f780e9",
        1022,
    ),
    (
        "data/ground-truths/Nikon_D700_Jiang-et-al-2013.csv",
        "4a1e15cb1f2b4d6859d9463b788a5b223ede47ae51c33b0a0b75936ff295e4de",
        1030,
    ),
    (
        "data/ground-truths/Nikon_D700_Mauer-2009.csv",
        "7cb3f1fd3876f15d0dfcaee053cc42e80cec20f0d9269727af804047c1931b97",
        649,
    ),
    (
        "data/ground-truths/Nikon_D70_Huynh-2007.csv",
        "6b20872c745dd1ef1ca5173a8be26cf12f9ec6bf7fce37df01ae59461f84a8c0",
        1017,
    ),
    (
        "data/ground-truths/Nikon_D70_Kawakami-et-al-2013.csv",
        "ce18de899e11d389182fc1dbabc1641f125ee5a1dd7e6e7ca1bb3dc2fbadb090",
        1020,
    ),
    (
        "data/ground-truths/Nikon_D90_Jiang-et-al-2013.csv",
        "a0e49479714d58442be5edbc1a28169ae5fd5c3c8db2fc0fd38c7ada9ca1c4d3",
        1025,
    ),
    (
        "data/ground-truths/Olympus_EPL2_Jiang-et-al-2013.csv",
        "02bb3a687810ee7f0622622d11956def5a0ca5c8b4c4b02718216d9488748945",
        1021,
    ),
    (
        "data/ground-truths/Panasonic_DMC-LX3_Mauer-2009.csv",
        "ceeeea4201e6ec747580c5e04baff18beb97e0a86e7fb909bcf0f58defe6ec53",
        660,
    ),
    (
        "data/ground-truths/Panasonic_DMCL-X5_Berra-et-al-2015.csv",
        "3cbd683b32ce62e8990614d03546ae1d7cf41bb41a0d034dd914cb084c32f7ad",
        993,
    ),
    (
        "data/ground-truths/Pentax_K5_Jiang-et-al-2013.csv",
        "388bd6b48360779ceba12274ea83eff7429b120f4d654d79db3dda8cf4e72ab5",
        1015,
    ),
    (
        "data/ground-truths/Pentax_Q_Jiang-et-al-2013.csv",
        "b734c24e406127d7c2c48f0acf8472d8dc35ef5967621c79756031aeb86d8918",
        999,
    ),
    (
        "data/ground-truths/Samsung_Galaxy-S20_Tominaga_etal_2021.csv",
        "0af012d07f3eb5322ef78bad37d81cf220f45e09603d32ddeb7622ce85837830",
        810,
    ),
    (
        "data/ground-truths/Samsung_Galaxy-S7-Edge_Tominaga_etal_2021.csv",
        "90c681c7fd4a9e5a9831f80deb9902afd3c67f3edd3184e4b4378a6f3bcae3a2",
        817,
    ),
    (
        "data/ground-truths/Samsung_Galaxy-S8_Burggraaff_etal_2019.csv",
        "f4707ec69398aacd86ca904763573f6f26885ea683afec7ca3662d610f715bb9",
        1919,
    ),
    (
        "data/ground-truths/Samsung_Galaxy-S9_Tominaga_etal_2021.csv",
        "906967c317dc8e7c5c93c2802ccba0df89b62c62c7df2c3f4e864d24b6e45432",
        807,
    ),
    (
        "data/ground-truths/Sony_NEX5N_Jiang-et-al-2013.csv",
        "d3f171aac201e6137ed0b531d3f8dadd0807359f78e3f951dfb7452e5f652dcc",
        1014,
    ),
    (
        "data/ground-truths/Sony_NEX7_Berra-et-al-2015.csv",
        "4691cb47196ffdaa8c77b2c03a820839fa44424ed314cd53b5c74a62ea344d9c",
        1003,
    ),
    (
        "data/ground-truths/iPhone_10_Tominaga_etal_2021.csv",
        "c7c1ff318946a3bbd5241f05beb5d63ae195b8530c17c139c45471d8a34a7dfa",
        819,
    ),
    (
        "data/ground-truths/iPhone_11_Tominaga_etal_2021.csv",
        "ba3059960f36fe3b3b40727ac0d79be6fcd2b627d8b6ad90356d130480e4d95f",
        814,
    ),
    (
        "data/ground-truths/iPhone_12-Pro-Max_Tominaga_etal_2021.csv",
        "4cf716d73cd95512d4ccad4991d6a07ada566915b75c0c1618d930c8fa625819",
        814,
    ),
    (
        "data/ground-truths/iPhone_8_Tominaga_etal_2021.csv",
        "02b7ffe9b2a28523cc4b93f0f5a1bfd5e06a60c573701109fdb8579172de3680",
        819,
    ),
    (
        "data/ground-truths/test-data/Nikon_D80_Jiang-et-al-2013.csv",
        "1775a764bb83a25be656a53ffa69844c9e069b034a6477b251f30552bf1c9588",
        1047,
    ),
    (
        "data/wavelengths.csv",
        "2cf9a96f15005325f9792f696879666bf84761d40e52996524e98b01f1d8965a",
        186,
    ),
)


_PINNED_SOURCES.update(
    {
        SOLOMATOV: (
            "COLOR-Lab-Eilat/Spectral-sensitivity-estimation",
            "e9958089605676c27437ea98665490d40f104d5d",
            _FILES_SOLOMATOV_AKKAYNAK_2023,
        ),
        CAMSPEC: (
            "supersasha/difp-electron",
            "6735425e38108de69b412d5273472fa068d75eae",
            _FILES_JIANG_2013_CAMSPEC,
        ),
        BUTCHERG: (
            "butcherg/ssf-data",
            "ae8620d680877716671c0f0772ef4e625eb9039c",
            _FILES_BUTCHERG_SSF_DATA,
        ),
        RAWTOACES: (
            "AcademySoftwareFoundation/rawtoaces",
            "300324c09fcc8bf19ac5066100c85d1022589b48",
            _FILES_RAWTOACES,
        ),
    }
)

#: The collections ``data fetch`` downloads.
FETCHABLE_COLLECTIONS: tuple[str, ...] = tuple(_PINNED_SOURCES)
