"""vkdt's spectral sensitivity text (``vkdt-mkclut <model>`` reads ``<model>.txt``).

Plain text, one row per wavelength ``λ R G B`` separated by spaces, 380–780 nm in 5 nm steps, no
header and no comments (vkdt's own ``data/*.txt`` examples are exactly this). vkdt names the file
after the camera (``Nikon_D5100.txt``) and writes ``<model>.lut`` beside it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.core.camera_curves import CameraCurves
from calib.core.errors import InputError
from calib.core.formats.ampas import RAWTOACES_GRID


def write_vkdt_txt(path: Path, curves: CameraCurves) -> Path:
    """Write ``curves`` (on 380–780 nm / 5 nm) as vkdt text."""
    if not curves.is_on(RAWTOACES_GRID):
        raise InputError(
            "vkdt reads 380–780 nm at 5 nm; extend the curves first", source=curves.name
        )
    lines = [
        f"{round(float(w))} " + " ".join(repr(float(v)) for v in row)
        for w, row in zip(curves.wavelength_nm, curves.values, strict=True)
    ]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    return path


def read_vkdt_txt(path: str | Path) -> CameraCurves:
    """Read a vkdt ``λ R G B`` text file.

    Raises
    ------
    InputError
        Missing file, not four numeric columns (the file is named).
    """
    path = Path(path)
    try:
        rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except FileNotFoundError:
        raise InputError("file not found", source=str(path)) from None
    except ValueError as exc:
        raise InputError(f"not vkdt text (λ R G B per line): {exc}", source=str(path)) from None
    if rows.shape[1] != 4:
        raise InputError(f"{rows.shape[1]} columns; vkdt text has 4 (λ R G B)", source=str(path))
    return CameraCurves(rows[:, 0], rows[:, 1:], name=path.stem)
