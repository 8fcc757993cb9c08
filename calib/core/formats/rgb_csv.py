"""Camera sensitivities as CSV: columns by name, with σ and a header saying what the numbers are.

Written (:func:`write_camera_csv`)::

    wavelength_nm,R,G,B,R_sigma,G_sigma,B_sigma
    # spectral-rig camera sensitivity …: relative units, maximum over all channels = 1
    # …
    400,0.0123,…

The column names come first so that readers taking the first line as the header (colour-science's
``read_sds_from_csv_file``, numpy's ``genfromtxt(names=True)``, spreadsheet programs) name the
columns; the ``#`` lines after it say the units, the normalisation and where σ comes from, and are
skipped by those readers as comments. σ is ``nan`` where it is unknown.

Read (:func:`read_camera_csv`): the wavelength and the channels by name in any order (``r``/``red``/
``R``…, :data:`calib.core.spectra.CHANNEL_COLUMNS`), σ columns optional, anything else refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from calib.core.camera_curves import CHANNEL_LABELS, CameraCurves
from calib.core.errors import InputError, SpectrumError
from calib.core.spectra import read_table


def _number(value: float) -> str:
    """Shortest text that round-trips a float64 (``nan`` for an unknown σ)."""
    return repr(float(value)) if np.isfinite(value) else "nan"


def write_camera_csv(path: Path, curves: CameraCurves, comments: Sequence[str] = ()) -> Path:
    """Write ``wavelength_nm,R,G,B`` (``,R_sigma,G_sigma,B_sigma`` when σ is known), then one
    ``# …`` line per comment, then the rows."""
    header = ["wavelength_nm", *CHANNEL_LABELS]
    columns = [curves.wavelength_nm[:, None], curves.values]
    if curves.sigma is not None:
        header += [f"{label}_sigma" for label in CHANNEL_LABELS]
        columns.append(curves.sigma)
    body = np.concatenate(columns, axis=1)
    lines = [",".join(header)]
    lines += [f"# {line}" for comment in comments for line in comment.splitlines()]
    for row in body:
        wavelength = float(row[0])
        key = str(round(wavelength)) if wavelength.is_integer() else repr(wavelength)
        lines.append(",".join([key, *(_number(v) for v in row[1:])]))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def read_camera_csv(
    path: str | Path, *, name: str | None = None, channels_in_order: bool = False
) -> CameraCurves:
    """A camera CSV, columns by name: ``wavelength_nm, R, G, B`` (any order, ``r``/``red``/``R``…)
    and optionally ``R_sigma, G_sigma, B_sigma``.

    Parameters
    ----------
    path
        The file (``#`` comment lines are skipped wherever they are).
    name
        The camera's name (default: the file name).
    channels_in_order
        Accept a file without a header as ``wavelength, R, G, B`` in that order: only for a
        collection whose documented layout says so (butcherg's CSVs).

    Raises
    ------
    SpectrumError
        No header (unless ``channels_in_order``), a channel missing or named twice, unknown
        columns, text in a row (the file and the columns are named).
    """
    table = read_table(path)
    label = name or table.path.name
    if not table.had_header and channels_in_order:
        if len(table.columns) != 4:
            raise SpectrumError(
                f"expected 4 columns (wavelength, R, G, B), found {len(table.columns)}",
                source=str(table.path),
            )
        wavelength, channels, sigmas = 0, (1, 2, 3), None
    else:
        wavelength = table.wavelength_index()
        channels, sigmas = table.rgb_indices()
    rows = table.rows[np.argsort(table.rows[:, wavelength], kind="stable")]
    values = rows[:, list(channels)]
    if not np.all(np.isfinite(values)):
        raise SpectrumError("a sensitivity is NaN or infinite", source=str(table.path))
    sigma = None if sigmas is None else rows[:, list(sigmas)]
    try:
        return CameraCurves(rows[:, wavelength], values, sigma, name=label)
    except InputError as exc:
        raise SpectrumError(str(exc).removeprefix(f"{label}: "), source=str(table.path)) from None
