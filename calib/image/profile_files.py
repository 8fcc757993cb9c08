"""1-D RGB profiles from the files other tools write: rawproc ``.dat`` exports and FITS planes.

A user who reduced a grating capture elsewhere brings what that tool wrote, not a CSV; these
readers turn it into an :class:`RgbProfile` (pixel axis, R, G, B, and σ where the file allows
one) with no conversion script.

rawproc ``.dat`` (Glenn Butcher's raw processor, "data" export of a cropped image)
    Header lines ``width: N`` and ``height: M``, then the rawproc command that made the image
    (e.g. ``rawproc-0.9.1Dev DSG_4683.NEF:rawdata=crop; demosaic:half rotate:hmirror crop:…``),
    then a row ``x,0,1,…,N−1``, rows ``red,…``, ``green,…``, ``blue,…`` holding the *column means*
    of the ``M`` rows of the crop (linear 0–1), and trailing ``rmax: V rmaxcolumn: C`` lines (also
    ``gmax``, ``bmax``) that are checked against the rows. The command's ``rotate`` steps say how
    the columns run with respect to the sensor's: a ``hmirror`` or a half turn (``rotate:180``)
    reverses them, a ``vmirror`` keeps them, two reversals cancel. The profile keeps the file's
    order (where the wavelength usually increases with ``x``) unless ``sensor_orientation=True``.
    A net quarter turn (``rotate:90``, ``rotate:270``) makes the file's columns the sensor's rows:
    warned, and refused with ``sensor_orientation=True``. The file holds means only, so the
    profile has no σ (the estimators then use a robust noise estimate).

    The command is read (:func:`parse_rawproc_command`, :func:`rawproc_findings`): the estimate
    needs the camera's linear channels at its raw gains. An operation that makes the data
    non-linear or mixes the channels (gamma, a tone curve, saturation, a colour conversion, gray,
    highlight recovery) is refused; a white balance by stated multipliers is undone exactly; one
    whose multipliers are not stated (camera, auto, patch), or an input opened without
    ``rawdata``, leaves the gains unknown (:attr:`RgbProfile.channel_gains_unknown`); a tool whose
    steps the command does not show, or that this reader does not know, is warned about.
FITS (through astropy, an optional dependency: ``pip install 'spectral-rig[fits]'``)
    One 2-D image per colour plane (three files R, G, B) or one cube with three planes. The
    spectral axis runs along the image's x (``NAXIS1``) by default. The profile is the *sum* over
    the band's cross-dispersion rows (found as the rows whose mean reaches ``band_fraction`` of the
    brightest, or given), less the per-column background of the rows outside the band when there
    are enough of them. σ comes from the rows' scatter about a separable model ``a_row · m_column``
    (the band's cross-section times the spectrum) — shot and read noise alike — and is inflated
    by the correlation between neighbouring rows that a demosaicked plane has (its rows share raw
    samples, so their scatter understates the noise of their sum).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from calib.core.arrays import FloatArray
from calib.core.errors import InputError
from calib.core.observations import CHANNEL_GAINS_KEY, LampKind, LampObservation
from calib.core.spectra import Spectrum

CHANNELS: tuple[str, str, str] = ("red", "green", "blue")
#: Relative tolerance of the trailing ``rmax:`` lines against the rows' own maxima (the file
#: prints six decimals).
RAWPROC_MAX_TOLERANCE = 5e-6
#: Fewer rows outside the band than this: no background is subtracted.
MIN_BACKGROUND_ROWS = 4
#: Columns over which each column's scatter is averaged (it rests on few rows per column).
SCATTER_SMOOTHING_COLUMNS = 7
#: Columns sharing one fitted cross-section of the band in the σ model.
CROSS_SECTION_BLOCK_COLUMNS = 64
#: Neighbouring-row lags whose correlation inflates the σ of a sum over rows.
CORRELATION_LAGS = 2
FITS_EXTRA_HINT = "reading FITS needs astropy: pip install 'spectral-rig[fits]' (or astropy>=6.0)"


@dataclass(frozen=True, eq=False)
class RgbProfile:
    """A 1-D first-order profile read from a file.

    Attributes
    ----------
    pixel
        Shape ``(n,)``, increasing: the column of each sample (the file's own pixel axis).
    profile
        Shape ``(n, 3)``: R, G, B in the file's linear units.
    profile_sigma
        Shape ``(n, 3)`` standard deviation, or ``None`` when the file does not allow one.
    source
        The file(s) read.
    metadata
        What the file says about how it was made (JSON-safe): the processing command and its
        operations, rows averaged or summed, mirroring, header keywords.
    channel_gains_unknown
        Why the file's channels are not at the raw data's gains by amounts it states (e.g. a
        rawproc ``whitebalance:camera``), or ``None`` when it says nothing of the kind.
    image_planes
        The profile was reduced from an RGB image's colour planes (a FITS export): a conversion
        may have balanced its channels, and the file cannot say whether one did.
    warnings, notes
        What reading found that the user should hear (an operation that could not be checked) or
        may want to know (white-balance multipliers undone).
    """

    pixel: FloatArray
    profile: FloatArray
    profile_sigma: FloatArray | None
    source: str
    metadata: Mapping[str, Any] = field(default_factory=dict)
    channel_gains_unknown: str | None = None
    image_planes: bool = False
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        pixel = np.array(self.pixel, dtype=np.float64)
        profile = np.array(self.profile, dtype=np.float64)
        if profile.shape != (pixel.size, 3):
            raise InputError(
                f"profile has shape {profile.shape}, expected ({pixel.size}, 3)", source=self.source
            )
        for array in (pixel, profile):
            array.flags.writeable = False
        object.__setattr__(self, "pixel", pixel)
        object.__setattr__(self, "profile", profile)
        if self.profile_sigma is not None:
            sigma = np.array(self.profile_sigma, dtype=np.float64)
            sigma.flags.writeable = False
            object.__setattr__(self, "profile_sigma", sigma)

    def to_observation(
        self,
        name: str,
        spectrum: Spectrum,
        *,
        kind: LampKind = "other",
        direct_rgb: Sequence[float] | None = None,
        spectrum_bandwidth_nm: float | None = None,
    ) -> LampObservation:
        """The estimators' input: this profile with the lamp's spectrum (pixel origin arbitrary);
        a profile whose gains are unknown is marked so (``channel_gains: unknown``)."""
        gains = {} if self.channel_gains_unknown is None else {CHANNEL_GAINS_KEY: "unknown"}
        return LampObservation(
            name=name,
            spectrum=spectrum,
            pixel=self.pixel,
            profile=self.profile,
            direct_rgb=None if direct_rgb is None else np.asarray(direct_rgb, dtype=np.float64),
            profile_sigma=self.profile_sigma,
            kind=kind,
            metadata={"profile_file": self.source, **dict(self.metadata), **gains},
            spectrum_bandwidth_nm=spectrum_bandwidth_nm,
        )


# ----------------------------------------------------------------------------------- rawproc


def _numbers(fields: list[str], where: str) -> FloatArray:
    try:
        values = np.array([float(text) for text in fields], dtype=np.float64)
    except ValueError:
        bad = next(text for text in fields if not _is_number(text))
        raise InputError(f"{bad!r} is not a number", source=where) from None
    if not np.all(np.isfinite(values)):
        raise InputError("contains NaN or infinite values", source=where)
    return values


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


_MAX_LINE = re.compile(
    r"^(?P<channel>[rgb])max:\s*(?P<value>\S+)(?:\s+\wmaxcolumn:\s*(?P<column>\d+))?"
)


# The rawproc command (the .dat header's third line): the program and version, the input file and
# its options (``DSG_4683.NEF:rawdata=crop;``), then one token per tool, ``name:params`` with
# positional ``a,b,c``, ``name=val;…`` or JSON parameters (rawproc's gimage_parse.cpp).

#: Input options that mean "raw data, no LibRaw processing" (``rawdata=crop`` or ``rawdata=1``).
_RAWDATA_OFF = ("", "0", "false", "no")
#: Inputs that cannot hold linear data: 8-bit, gamma-encoded images.
_ENCODED_INPUTS = (".jpg", ".jpeg", ".png")
#: Tools that keep each channel linear and its gain: geometry, resampling, smoothing, a common
#: scale (exposure, banding) or offset (add, subtract — a dark frame is good practice).
_RAWPROC_KEEPS = frozenset(
    {
        "add",
        "banding",
        "cacorrect",
        "crop",
        "cropspectrum",
        "demosaic",
        "denoise",
        "exposure",
        "lenscorrection",
        "lensdistortion",
        "lensvignetting",
        "resize",
        "rotate",
        "sharpen",
        "spot",
        "subtract",
    }
)
#: Tools that are non-linear or mix the channels, whatever their parameters, and why.
_RAWPROC_BREAKS = {
    "bright": "applies a brightness curve, which makes the profile non-linear",
    "contrast": "applies a contrast curve, which makes the profile non-linear",
    "gray": "mixes the three channels into one gray",
    "grayscale": "mixes the three channels into one gray",
    "highlight": "applies a highlight tone curve, which makes the profile non-linear",
    "hlrecover": "rebuilds clipped channels from the others, which mixes the channels",
    "lut": "applies a look-up table, which makes the profile non-linear",
    "ocio": "applies a colour transform, which mixes the channels",
    "redeye": "desaturates red patches, which mixes the channels",
    "shadow": "applies a shadow tone curve, which makes the profile non-linear",
    "tonemask": "applies a tone mask, which makes the profile non-linear",
}
#: Tools whose steps the command does not show (a file of commands, a script, a G'MIC line).
_RAWPROC_HIDES = frozenset({"gmic", "group", "script"})
#: Tools whose effect depends on their parameters (each read in :func:`_operation_finding`).
_RAWPROC_BY_PARAMETERS = frozenset(
    {"blackwhitepoint", "colorspace", "curve", "gamma", "saturation", "tone", "whitebalance"}
)
#: Every tool name this reader knows: the end of an input's name is found before one.
_RAWPROC_TOOLS = (
    _RAWPROC_KEEPS | _RAWPROC_HIDES | frozenset(_RAWPROC_BREAKS) | _RAWPROC_BY_PARAMETERS
)
_CHANNEL_NAMES = ("rgb", "red", "green", "blue")


@dataclass(frozen=True)
class RawprocOperation:
    """One tool of a rawproc command: ``name`` (lower case) and its parameter text as written."""

    name: str
    params: str = ""

    @property
    def label(self) -> str:
        """The operation as the command wrote it (``gamma:2.2``)."""
        return f"{self.name}:{self.params}" if self.params else self.name

    def positional(self) -> list[str]:
        """The comma-separated parameters, stripped and lower-cased (``[]`` when none)."""
        return [part.strip().lower() for part in self.params.split(",")] if self.params else []

    def named(self) -> dict[str, str]:
        """The ``name=val;…`` or JSON parameters (keys lower-cased), ``{}`` for positional ones."""
        text = self.params.strip()
        if text.startswith("{"):
            try:
                loaded = json.loads(text)
            except json.JSONDecodeError:
                return {}
            return (
                {str(k).lower(): str(v) for k, v in loaded.items()}
                if isinstance(loaded, dict)
                else {}
            )
        if "=" not in text:
            return {}
        pairs = (item.split("=", 1) for item in text.split(";") if "=" in item)
        return {key.strip().lower(): value.strip() for key, value in pairs}


@dataclass(frozen=True)
class RawprocCommand:
    """A rawproc command read by :func:`parse_rawproc_command`.

    Attributes
    ----------
    program
        ``rawproc-0.9.1Dev``: the program and its version.
    input_file
        The image rawproc opened.
    input_options
        Its input options (``{"rawdata": "crop"}``).
    operations
        The tools, in the order applied.
    parse_warning
        Why where the input's name ends could not be told from the operations (the name is then
        read as far as its first space), or ``None``.
    """

    program: str
    input_file: str
    input_options: Mapping[str, str]
    operations: tuple[RawprocOperation, ...]
    parse_warning: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form (for the profile's metadata and the result's provenance)."""
        return {
            "program": self.program,
            "input_file": self.input_file,
            "input_options": dict(self.input_options),
            "operations": [{"name": op.name, "params": op.params} for op in self.operations],
        }


def _command_tokens(text: str) -> list[str]:
    """Whitespace-separated tokens, a JSON parameter block kept whole across its spaces."""
    tokens: list[str] = []
    depth = 0
    for word in text.split():
        if depth > 0:
            tokens[-1] += " " + word
        else:
            tokens.append(word)
        depth = max(depth + word.count("{") - word.count("}"), 0)
    return tokens


#: The word that ends the input's name: ``….NEF`` or ``….NEF:rawdata=crop;`` (the first colon
#: after an extension, so a Windows drive's colon is no end).
_INPUT_END = re.compile(r"^(?P<name>.*?\.[A-Za-z][A-Za-z0-9]*)(?::(?P<options>.*))?$")


def _split_input(text: str) -> tuple[str, str, str] | None:
    """``text`` (the command after the program) as the input's name, its options and the rest.

    rawproc writes the input as ``name:options`` (``name`` alone when it has none) and then each
    tool, all separated by spaces, so a name with spaces has no delimiter of its own. The name
    ends at the first word that ends in an extension and either carries the input's options or is
    followed by a tool's name (or nothing); ``None`` when no word does.
    """
    words = list(re.finditer(r"\S+", text))
    for index, word in enumerate(words):
        match = _INPUT_END.match(word.group())
        if match is None:
            continue
        following = words[index + 1].group() if index + 1 < len(words) else ""
        next_tool = following.partition(":")[0].lower()
        if match["options"] is not None or not following or next_tool in _RAWPROC_TOOLS:
            name = text[words[0].start() : word.start()] + match["name"]
            return name, match["options"] or "", text[word.end() :]
    return None


def parse_rawproc_command(line: str) -> RawprocCommand:
    """Read a rawproc command line into its input and its ordered operations.

    ``"rawproc-0.9.1Dev DSG_4683.NEF:rawdata=crop;  demosaic:half rotate:hmirror crop:0,0.4,1,0.5"``
    gives the input ``DSG_4683.NEF`` with ``{"rawdata": "crop"}`` and three operations; so does
    ``My Shot 01.NEF:rawdata=crop; …`` with the input ``My Shot 01.NEF`` (:func:`_split_input`).
    When the input's end cannot be told, its name is read as far as its first space (the rest
    then shows as unknown operations) and :attr:`RawprocCommand.parse_warning` says so.

    Examples
    --------
    >>> command = parse_rawproc_command("rawproc-0.9 My Shot.NEF:rawdata=crop; rotate:180")
    >>> command.input_file, [op.label for op in command.operations]
    ('My Shot.NEF', ['rotate:180'])
    """
    program, _, rest = line.strip().partition(" ")
    split = _split_input(rest)
    warning = None
    if split is None:
        first, _, after = rest.strip().partition(" ")
        name, _, options_text = first.partition(":")
        warning = (
            f"where the rawproc command's input {name!r} ends cannot be told (no word ending in "
            "an extension before a rawproc tool); its name is read as far as its first space"
        )
        split = (name, options_text, after)
    input_file, options_text, operations_text = split
    options: dict[str, str] = {}
    for item in options_text.split(";"):
        key, _, value = item.partition("=")
        if key.strip():
            options[key.strip().lower()] = value.strip()
    operations = []
    for token in _command_tokens(operations_text):
        name, _, params = token.partition(":")
        operations.append(RawprocOperation(name.strip().lower(), params.strip()))
    return RawprocCommand(program, input_file, options, tuple(operations), warning)


RawprocEffect = Literal["keeps", "undone", "gains_unknown", "refused", "unchecked"]


@dataclass(frozen=True)
class RawprocFinding:
    """What one step of a rawproc command does to the channels.

    ``effect``: ``keeps`` (linear, the raw gains kept), ``undone`` (channel multipliers stated in
    ``multipliers``, divided out on reading), ``gains_unknown`` (channels scaled by amounts the
    command does not state), ``refused`` (non-linear or channel-mixing), ``unchecked`` (a tool
    whose steps are hidden, or unknown to this reader). ``reason`` completes "the command's
    ``label`` …".
    """

    label: str
    effect: RawprocEffect
    reason: str = ""
    multipliers: tuple[float, float, float] | None = None


def _floats(texts: Sequence[str]) -> list[float] | None:
    try:
        values = [float(text) for text in texts]
    except ValueError:
        return None
    return values if all(math.isfinite(v) for v in values) else None


def _whitebalance(op: RawprocOperation) -> RawprocFinding:
    named, positional = op.named(), op.positional()
    keys = ("redmultiplier", "greenmultiplier", "bluemultiplier")
    if named:
        mode = named.get("mode", "multipliers").lower()
        stated = [named.get(key, "") for key in keys]
    else:
        first = positional[0] if positional else ""
        mode = "multipliers" if _floats([first]) is not None else first
        stated = positional[:3]
    if mode == "bluethreshold":
        return RawprocFinding(
            op.label,
            "refused",
            "scales the channels only where blue passes a threshold, which makes the profile "
            "non-linear",
        )
    if mode == "multipliers":
        multipliers = _floats(stated) if len(stated) == 3 else None
        if multipliers is None or min(multipliers) <= 0:
            return RawprocFinding(op.label, "refused", "states no three multipliers above 0")
        red, green, blue = multipliers
        return RawprocFinding(op.label, "undone", "multiplied the channels", (red, green, blue))
    said = {
        "camera": "the camera's as-shot multipliers",
        "auto": "gray-world multipliers computed from the image",
        "patch": "multipliers computed from a patch of the image",
    }.get(mode, "multipliers it does not state")
    return RawprocFinding(op.label, "gains_unknown", f"scaled the channels by {said}")


def _blackwhitepoint(op: RawprocOperation) -> RawprocFinding:
    named, positional = op.named(), op.positional()
    channel = named.get("channel", "rgb").lower() if named else "rgb"
    if positional and positional[0] in _CHANNEL_NAMES:
        channel = positional[0]
    if channel == "rgb":
        return RawprocFinding(op.label, "keeps", "one black and one white point for all channels")
    return RawprocFinding(
        op.label,
        "gains_unknown",
        f"set the {channel} channel's black and white points alone, which rescaled that channel "
        "(by a factor rawproc versions compute differently)",
    )


def _is_one(texts: Sequence[str]) -> bool:
    values = _floats(texts)
    return values is not None and len(values) == 1 and values[0] == 1.0


def _identity_curve(coordinates: list[str]) -> bool:
    """A ``curve`` whose control points all lie on y = x (rawproc's default curve)."""
    values = _floats(coordinates)
    if not values or len(values) % 2:
        return False
    return all(x == y for x, y in zip(values[::2], values[1::2], strict=True))


def _operation_finding(op: RawprocOperation) -> RawprocFinding:
    """The effect of one tool on the channels (module docstring; rawproc's tool list)."""
    name, positional, named = op.name, op.positional(), op.named()
    if name in _RAWPROC_KEEPS:
        if name == "demosaic" and positional[:1] == ["color"]:
            return RawprocFinding(op.label, "refused", "paints the mosaic in the pattern's colours")
        return RawprocFinding(op.label, "keeps")
    if name == "whitebalance":
        return _whitebalance(op)
    if name == "blackwhitepoint":
        return _blackwhitepoint(op)
    after_channel = positional[1:] if positional[:1] and positional[0] in _CHANNEL_NAMES else None
    linear = {
        "gamma": lambda: _is_one(positional[:1]) or _is_one([named.get("gamma", "")]),
        "tone": lambda: positional[:1] == ["gamma"] and _is_one(positional[1:2]),
        "curve": lambda: _identity_curve(positional if after_channel is None else after_channel),
        "saturation": lambda: _is_one(
            [named.get("saturation", "")] if named else (after_channel or positional)[:1]
        ),
    }
    if name in linear:
        if linear[name]():
            return RawprocFinding(op.label, "keeps")
        why = "mixes the channels" if name == "saturation" else "makes the profile non-linear"
        return RawprocFinding(op.label, "refused", why)
    if name == "colorspace":
        assigned = named.get("op", "").lower() == "assign" or "assign" in positional
        if assigned:
            return RawprocFinding(op.label, "keeps", "assigns a profile and changes no pixel")
        return RawprocFinding(
            op.label, "refused", "converts the colours through a matrix, which mixes the channels"
        )
    if name in _RAWPROC_BREAKS:
        return RawprocFinding(op.label, "refused", _RAWPROC_BREAKS[name])
    if name in _RAWPROC_HIDES:
        return RawprocFinding(op.label, "unchecked", "runs steps the command does not show")
    return RawprocFinding(op.label, "unchecked", "is not a rawproc tool this reader knows")


def rawproc_findings(command: RawprocCommand) -> list[RawprocFinding]:
    """What the input and each operation of ``command`` do to the channels, in order.

    The input comes first: opened without ``rawdata`` LibRaw processed it as then configured
    (white balance, colour conversion unknown), and a JPEG or PNG is gamma-encoded.
    """
    rawdata = command.input_options.get("rawdata")
    label = f"input {command.input_file}" + (
        f":{';'.join(f'{k}={v}' for k, v in command.input_options.items())}"
        if command.input_options
        else ""
    )
    if Path(command.input_file).suffix.lower() in _ENCODED_INPUTS:
        first = RawprocFinding(label, "refused", "is a gamma-encoded 8-bit image")
    elif rawdata is None or rawdata.lower() in _RAWDATA_OFF:
        first = RawprocFinding(
            label,
            "gains_unknown",
            "was opened without rawdata=crop, so LibRaw's white balance and colour conversion "
            "(unknown here) were applied",
        )
    else:
        first = RawprocFinding(label, "keeps")
    return [first, *(_operation_finding(op) for op in command.operations)]


def _undo_command(
    profile: FloatArray, command: RawprocCommand | None, path: Path
) -> tuple[FloatArray, dict[str, Any], str | None, list[str], list[str]]:
    """Apply the command's findings to ``profile``: refuse (InputError naming the file and the
    operation), divide stated multipliers out, and say what is unknown or unchecked.

    Returns the profile, the command's metadata, why the gains are unknown (or ``None``), the
    warnings and the notes."""
    if command is None:
        warning = (
            f"{path.name}: the file holds no rawproc command line, so its processing cannot be "
            "checked; the profile is taken as raw, linear data"
        )
        return profile, {}, None, [warning], []
    findings = rawproc_findings(command)
    for finding in findings:
        if finding.effect == "refused":
            raise InputError(
                f"the rawproc command applies {finding.label}, which {finding.reason}; export the "
                "data again without it (raw data, demosaic:half, crop, rotate)",
                source=str(path),
            )
    undone = [f for f in findings if f.effect == "undone"]
    stated = [f.multipliers for f in undone if f.multipliers is not None]
    total = np.prod(np.array(stated), axis=0) if stated else np.ones(3)
    notes = []
    if undone:
        profile = profile / total
        notes.append(
            f"{path.name}: the rawproc command's {', '.join(f.label for f in undone)} multiplied "
            f"R, G, B by {', '.join(f'{v:g}' for v in total)}; divided out, so the profile is at "
            "the raw data's gains"
        )
    unknown = [f for f in findings if f.effect == "gains_unknown"]
    reason = (
        "; ".join(f"the rawproc command's {f.label} {f.reason}" for f in unknown)
        if unknown
        else None
    )
    warnings = [f"{path.name}: {command.parse_warning}"] if command.parse_warning else []
    warnings += [
        f"{path.name}: the rawproc command's {f.label} {f.reason}; it cannot be checked that it "
        "keeps the channels linear at their raw gains"
        for f in findings
        if f.effect == "unchecked"
    ]
    metadata = {
        **command.to_dict(),
        "findings": [
            {"operation": f.label, "effect": f.effect, **({"reason": f.reason} if f.reason else {})}
            for f in findings
        ],
        **({"undone_multipliers": [float(v) for v in total]} if undone else {}),
    }
    return profile, metadata, reason, warnings, notes


#: rawproc's mirrors as matrices on an image's (column, row) directions; its quarter turn.
_MIRRORS = {"hmirror": np.diag([-1, 1]), "vmirror": np.diag([1, -1])}
_QUARTER_TURN = np.array([[0, -1], [1, 0]], dtype=np.int64)


def _rotate_matrix(op: RawprocOperation) -> NDArray[np.int64] | None:
    """How a rawproc ``rotate`` moves the image's (column, row) directions, or ``None`` when its
    parameters name no rotation.

    As rawproc reads them (its ``parse_rotate``/``process_rotate``): ``hmirror`` or ``vmirror``
    (positional, or a named key), else an angle in degrees: 90, 180 and 270 are exact turns, any
    other turns freely (a straightening within ±45°); taken as the nearest quarter turn.
    """
    named = op.named()
    positional = [] if named else op.positional()
    for mirror, matrix in _MIRRORS.items():
        if mirror in named or positional[:1] == [mirror]:
            return matrix
    angle = _floats([named.get("angle", "")] if named else positional[:1])
    if angle is None:
        return None
    return np.linalg.matrix_power(_QUARTER_TURN, round(angle[0] / 90) % 4)


@dataclass(frozen=True)
class _Orientation:
    """The file's columns against the crop's sensor columns, from the command's ``rotate`` steps.

    ``reversed``: they run the other way (net hmirror or half turn); ``quarter_turn``: they are
    the sensor's rows; ``steps``: the rotate labels that moved them; ``unknown``: rotate labels
    that name no rotation (taken as none).
    """

    reversed: bool
    quarter_turn: bool
    steps: tuple[str, ...]
    unknown: tuple[str, ...]


def _orientation(command: RawprocCommand | None) -> _Orientation:
    total = np.eye(2, dtype=np.int64)
    steps: list[str] = []
    unknown: list[str] = []
    for op in () if command is None else command.operations:
        if op.name != "rotate":
            continue
        matrix = _rotate_matrix(op)
        if matrix is None:
            unknown.append(op.label)
            continue
        if matrix[0, 0] != 1:  # a vmirror or a straightening keeps the columns' direction
            steps.append(op.label)
        total = matrix @ total
    return _Orientation(
        bool(total[0, 0] == -1), bool(total[0, 0] == 0), tuple(steps), tuple(unknown)
    )


def read_rawproc_dat(path: str | Path, *, sensor_orientation: bool = False) -> RgbProfile:
    """Read a rawproc ``.dat`` export (see the module docstring) into a profile.

    Parameters
    ----------
    path
        The ``.dat`` file.
    sensor_orientation
        Undo the rawproc command's reversal of the columns (a net ``hmirror`` or half turn), so
        that the pixel axis runs as the sensor's columns (and the profile's order follows); by
        default the file's order is kept. Only the command's ``rotate`` steps are read: rawproc
        can also turn an image by its EXIF orientation through its own configuration
        (``output.orient``), which the file does not record, so with that setting on the
        sensor's order is not recoverable from the file (export with it off, or keep the file's
        order: the mapping search tries both directions).

    Raises
    ------
    InputError
        A missing or unreadable file, a missing ``width:``/``x``/``red``/``green``/``blue`` line,
        rows of the wrong length, text or NaN in a row, an ``x`` row that is not ``0 … width−1``,
        an ``rmax:``-style line that disagrees with its row (the file and line are named), or
        ``sensor_orientation`` asked of a file the command turned a quarter turn.

    Examples
    --------
    Not run as a doctest: it needs a rawproc export (``tests/test_profile_files.py`` reads written
    ones, and the real D7000 files when ``../shared`` is present).

    >>> profile = read_rawproc_dat("D7000_spectrum.dat")  # doctest: +SKIP
    >>> profile.profile.shape, profile.metadata["mirrored"]  # doctest: +SKIP
    ((2474, 3), True)
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        raise InputError("file not found", source=str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", source=str(path)) from None
    header: dict[str, int] = {}
    rows: dict[str, tuple[int, FloatArray]] = {}
    maxima: dict[str, tuple[int, float, int | None]] = {}
    command = ""
    for number, raw in enumerate(lines, start=1):
        line = raw.strip()
        where = f"{path} line {number}"
        if not line:
            continue
        key = line.split(",", 1)[0].split(":", 1)[0].strip().lower()
        if key in ("width", "height") and ":" in line:
            text = line.split(":", 1)[1].strip()
            if not text.isdigit() or int(text) <= 0:
                raise InputError(f"{key} must be a positive integer, got {text!r}", source=where)
            header[key] = int(text)
        elif key in ("x", *CHANNELS) and "," in line:
            if key in rows:
                raise InputError(f"a second {key!r} row", source=where)
            rows[key] = (number, _numbers(line.split(",")[1:], where))
        elif (match := _MAX_LINE.match(line)) is not None:
            column = match["column"]
            maxima[match["channel"]] = (
                number,
                float(_numbers([match["value"]], where)[0]),
                None if column is None else int(column),
            )
        elif line.lower().startswith("rawproc"):
            command = line
        else:
            raise InputError(
                f"unexpected line {line[:40]!r}; a rawproc .dat has width:, height:, the rawproc "
                "command, x/red/green/blue rows and rmax:/gmax:/bmax: lines",
                source=where,
            )
    missing = [name for name in ("width", "height") if name not in header]
    missing += [name for name in ("x", *CHANNELS) if name not in rows]
    if missing:
        raise InputError(
            f"not a rawproc data export: no {', '.join(missing)} line(s)", source=str(path)
        )
    width = header["width"]
    for name, (number, values) in rows.items():
        if values.size != width:
            raise InputError(
                f"the {name!r} row has {values.size} values, width says {width}",
                source=f"{path} line {number}",
            )
    x_line, x = rows["x"]
    if not np.array_equal(x, np.arange(width, dtype=np.float64)):
        raise InputError(f"the x row must be 0, 1, …, {width - 1}", source=f"{path} line {x_line}")
    profile = np.stack([rows[name][1] for name in CHANNELS], axis=1)
    for letter, (number, value, column) in maxima.items():
        channel = "rgb".index(letter)
        found = float(profile[:, channel].max())
        if abs(found - value) > RAWPROC_MAX_TOLERANCE * max(abs(value), 1.0) + 5e-7:
            raise InputError(
                f"{letter}max {value:g} disagrees with the {CHANNELS[channel]} row's maximum "
                f"{found:g}; the file is damaged or edited",
                source=f"{path} line {number}",
            )
        if column is not None and profile[column, channel] < found - 5e-7:
            raise InputError(
                f"{letter}maxcolumn {column} does not hold the {CHANNELS[channel]} row's maximum",
                source=f"{path} line {number}",
            )
    parsed = parse_rawproc_command(command) if command else None
    profile, processing, unknown, warnings, notes = _undo_command(profile, parsed, path)
    orientation = _orientation(parsed)
    moved = ", ".join(orientation.steps)
    warnings += [
        f"{path.name}: the rawproc command's {label} names no rotation rawproc knows; the "
        "columns are taken in the file's order"
        for label in orientation.unknown
    ]
    if orientation.quarter_turn:
        if sensor_orientation:
            raise InputError(
                f"the rawproc command's {moved} turn(s) the image a quarter turn, so the file's "
                "columns are the sensor's rows: there is no sensor column order to restore; read "
                "it in the file's order",
                source=str(path),
            )
        warnings.append(
            f"{path.name}: the rawproc command's {moved} turn(s) the image a quarter turn, so the "
            "profile runs along the sensor's rows: it is a spectrum only if the grating dispersed "
            "along them"
        )
    mirrored = orientation.reversed
    flipped = sensor_orientation and mirrored
    if flipped:
        profile = profile[::-1]
    metadata: dict[str, Any] = {
        "format": "rawproc data export",
        "command": command,
        "rawproc": processing,
        "rows_averaged": header["height"],
        "width": width,
        "mirrored": mirrored,
        **({"quarter_turn": True} if orientation.quarter_turn else {}),
        "pixel_axis": _pixel_axis(orientation, flipped),
        "units": "linear, 0-1 (column means)",
    }
    return RgbProfile(
        np.arange(width, dtype=np.float64),
        profile,
        None,
        str(path),
        metadata,
        channel_gains_unknown=unknown,
        warnings=tuple(warnings),
        notes=tuple(notes),
    )


def _pixel_axis(orientation: _Orientation, flipped: bool) -> str:
    """What the profile's pixel axis is, for its metadata."""
    said = ", ".join(step.removeprefix("rotate:") for step in orientation.steps)
    if orientation.quarter_turn:
        return f"sensor rows of the crop (rawproc {said})"
    if flipped or not orientation.reversed:
        return "sensor columns of the crop"
    return f"mirrored columns of the crop (rawproc {said})"


# -------------------------------------------------------------------------------------- FITS


@dataclass(frozen=True, eq=False)
class ChannelPlanes:
    """Three colour planes of one image and their FITS headers.

    Attributes
    ----------
    planes
        Shape ``(3, rows, columns)``: R, G, B as stored (BZERO/BSCALE applied), float64.
    headers
        One header per plane, as plain ``{keyword: value}`` data.
    source
        The file(s) read.
    """

    planes: FloatArray
    headers: tuple[Mapping[str, Any], ...]
    source: str


def _fits_module() -> Any:
    try:
        from astropy.io import fits  # deferred: optional dependency, slow to import
    except ImportError:
        raise InputError(FITS_EXTRA_HINT, source="FITS") from None
    return fits


def _read_fits_image(path: Path) -> tuple[FloatArray, dict[str, Any]]:
    fits = _fits_module()
    try:
        with fits.open(path, memmap=False) as hdus:
            for hdu in hdus:
                if getattr(hdu, "data", None) is not None and getattr(hdu, "is_image", False):
                    data = np.asarray(hdu.data, dtype=np.float64)
                    header = {
                        str(k): v
                        for k, v in hdu.header.items()
                        if k and k not in ("COMMENT", "HISTORY")
                    }
                    return data, header
    except FileNotFoundError:
        raise InputError("file not found", source=str(path)) from None
    except OSError as exc:
        raise InputError(f"not a readable FITS file ({exc})", source=str(path)) from None
    raise InputError("the FITS file holds no image data", source=str(path))


def read_fits_planes(paths: str | Path | Sequence[str | Path]) -> ChannelPlanes:
    """R, G, B planes from three 2-D FITS images (in that order) or one cube of three planes.

    Raises
    ------
    InputError
        astropy missing (with the install line), a file that is not FITS or holds no image, planes
        of different shapes, NaN or infinite values, or a cube without exactly three planes.
    """
    files = [Path(paths)] if isinstance(paths, str | Path) else [Path(p) for p in paths]
    if len(files) not in (1, 3):
        raise InputError(
            f"give three FITS files (R, G, B) or one cube, got {len(files)}", source="FITS"
        )
    images = [_read_fits_image(path) for path in files]
    source = ", ".join(str(path) for path in files)
    if len(files) == 1:
        data, header = images[0]
        if data.ndim != 3 or 3 not in (data.shape[0], data.shape[-1]):
            raise InputError(
                f"one file must be a cube of 3 colour planes, got shape {data.shape}; or give "
                "the R, G and B planes as three files",
                source=source,
            )
        planes = data if data.shape[0] == 3 else np.moveaxis(data, -1, 0)
        headers: tuple[Mapping[str, Any], ...] = (header,) * 3
    else:
        shapes = {data.shape for data, _ in images}
        if len(shapes) != 1 or next(iter(shapes)).__len__() != 2:
            raise InputError(
                f"the three planes must be 2-D images of one shape, got {sorted(shapes)}",
                source=source,
            )
        planes = np.stack([data for data, _ in images])
        headers = tuple(header for _, header in images)
    if not np.all(np.isfinite(planes)):
        raise InputError("the planes contain NaN or infinite values", source=source)
    planes = np.ascontiguousarray(planes, dtype=np.float64)
    planes.flags.writeable = False
    return ChannelPlanes(planes, headers, source)


def band_rows(planes: FloatArray, band_fraction: float = 0.5) -> tuple[int, int]:
    """``(first, stop)`` rows of the band: the contiguous run around the brightest row whose mean
    (over columns and channels) reaches ``band_fraction`` of the brightest row's.

    The planes are taken as dark-subtracted (a reduced FITS image is): a band that fills the frame
    keeps every row.
    """
    if not 0 < band_fraction < 1:
        raise InputError(f"band_fraction must lie in (0, 1), got {band_fraction}", source="band")
    across = planes.mean(axis=(0, 2))
    peak = int(np.argmax(across))
    inside = across >= band_fraction * float(across[peak])
    first, stop = peak, peak + 1
    while first > 0 and inside[first - 1]:
        first -= 1
    while stop < across.size and inside[stop]:
        stop += 1
    return first, stop


def _separable_residual(rows_signal: FloatArray, source: str) -> FloatArray:
    """``x − a ⊗ m`` for a band ``x`` of shape ``(rows, columns)``: the cross-section ``a`` (fitted
    per block of :data:`CROSS_SECTION_BLOCK_COLUMNS`, so vignetting along the band is not taken
    for noise) times each column's least-squares level ``m``."""
    residual = np.empty_like(rows_signal)
    for start in range(0, rows_signal.shape[1], CROSS_SECTION_BLOCK_COLUMNS):
        block = rows_signal[:, start : start + CROSS_SECTION_BLOCK_COLUMNS]
        cross_section = block.mean(axis=1)
        weight = float(cross_section @ cross_section)
        if weight <= 0:
            raise InputError(
                f"no signal in the band's columns {start}…{start + block.shape[1] - 1}",
                source=source,
            )
        level = cross_section @ block / weight
        residual[:, start : start + block.shape[1]] = block - np.outer(cross_section, level)
    return residual


def _row_correlation_inflation(residual: FloatArray) -> float:
    """``1 + 2 Σ_k (1 − k/n) ρ_k`` over lags ``k ≤ CORRELATION_LAGS`` of the residuals' row
    autocorrelation (pooled over columns), at least 1: the variance of a sum of ``n`` correlated
    rows over that of ``n`` independent ones."""
    n = residual.shape[0]
    variance = float(np.mean(residual**2))
    if n < 3 or variance <= 0:
        return 1.0
    inflation = 1.0
    for lag in range(1, min(CORRELATION_LAGS, n - 1) + 1):
        rho = float(np.mean(residual[lag:] * residual[:-lag])) / variance
        inflation += 2.0 * (1.0 - lag / n) * rho
    return max(inflation, 1.0)


def profile_from_planes(
    planes: ChannelPlanes,
    *,
    rows: tuple[int, int] | None = None,
    dispersion_axis: Literal["x", "y"] = "x",
    band_fraction: float = 0.5,
) -> RgbProfile:
    """Sum the band's cross-dispersion rows of each plane into a profile with σ (module docstring).

    Parameters
    ----------
    planes
        From :func:`read_fits_planes`.
    rows
        ``(first, stop)`` rows of the band (after turning ``dispersion_axis`` to x); default: found
        with :func:`band_rows`.
    dispersion_axis
        ``"x"`` when the spectrum runs along the image's columns (``NAXIS1``), ``"y"`` along rows.
    band_fraction
        Threshold of :func:`band_rows`.

    Raises
    ------
    InputError
        A band of fewer than 2 rows, or rows outside the image.
    """
    if dispersion_axis not in ("x", "y"):
        raise InputError(
            f"dispersion_axis must be 'x' or 'y', got {dispersion_axis!r}", source="FITS"
        )
    data = planes.planes if dispersion_axis == "x" else np.swapaxes(planes.planes, 1, 2)
    n_rows = data.shape[1]
    first, stop = band_rows(data, band_fraction) if rows is None else rows
    if not 0 <= first < stop <= n_rows or stop - first < 2:
        raise InputError(
            f"band rows {first}…{stop - 1} must lie inside 0…{n_rows - 1} and span ≥ 2 rows",
            source=planes.source,
        )
    band = data[:, first:stop, :]
    outside = np.concatenate([data[:, :first, :], data[:, stop:, :]], axis=1)
    background = (
        np.median(outside, axis=1)
        if outside.shape[1] >= MIN_BACKGROUND_ROWS
        else np.zeros((3, data.shape[2]))
    )
    n = band.shape[1]
    signal = band - background[:, None, :]
    profile = signal.sum(axis=1).T
    from scipy.ndimage import uniform_filter1d  # deferred: scipy.ndimage is slow to import

    sigma = np.empty_like(profile)
    inflation: list[float] = []
    for channel in range(3):
        residual = _separable_residual(signal[channel], f"{planes.source} ({CHANNELS[channel]})")
        scatter = np.sum(residual**2, axis=0) / max(n - 2, 1)
        scatter = uniform_filter1d(scatter, SCATTER_SMOOTHING_COLUMNS, mode="nearest")
        factor = _row_correlation_inflation(residual)
        inflation.append(factor)
        sigma[:, channel] = np.sqrt(np.maximum(n * scatter * factor, 0.0))
    positive = sigma[sigma > 0]
    floor = float(positive.min()) if positive.size else 1e-12
    sigma = np.maximum(sigma, floor)
    header = dict(planes.headers[0])
    metadata: dict[str, Any] = {
        "format": "FITS planes",
        "band_rows": [first, stop],
        "rows_summed": n,
        "background": "median of the rows outside the band"
        if outside.shape[1] >= MIN_BACKGROUND_ROWS
        else "none (the band fills the frame)",
        "dispersion_axis": dispersion_axis,
        "row_correlation_inflation": [round(f, 4) for f in inflation],
        "header": {
            key: value
            for key, value in header.items()
            if isinstance(value, str | int | float | bool)
            and key in ("INSTRUME", "EXPTIME", "ISOSPEED", "DATE-OBS", "PROGRAM", "BZERO")
        },
    }
    pixel = np.arange(profile.shape[0], dtype=np.float64)
    return RgbProfile(pixel, profile, sigma, planes.source, metadata, image_planes=True)


def read_fits_profile(
    paths: str | Path | Sequence[str | Path],
    *,
    rows: tuple[int, int] | None = None,
    dispersion_axis: Literal["x", "y"] = "x",
    band_fraction: float = 0.5,
) -> RgbProfile:
    """:func:`read_fits_planes` then :func:`profile_from_planes`.

    Examples
    --------
    Not run as a doctest: it needs FITS planes (``tests/test_profile_files.py`` reads written ones,
    and the real Canon 10D planes when ``../shared`` is present).

    >>> planes = [f"Solar Spectrum Canon EOS 10D {c}.fit" for c in "RGB"]  # doctest: +SKIP
    >>> read_fits_profile(planes).profile.shape  # doctest: +SKIP
    (1658, 3)
    """
    return profile_from_planes(
        read_fits_planes(paths),
        rows=rows,
        dispersion_axis=dispersion_axis,
        band_fraction=band_fraction,
    )
