"""Profiles from other tools' files: rawproc .dat exports and FITS planes (calib.image.profile_files)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.spectra import Spectrum
from calib.image.profile_files import (
    parse_rawproc_command,
    read_fits_planes,
    read_fits_profile,
    read_rawproc_dat,
)
from calib.pipeline.estimate import OfflineSettings, _check_inputs
from calib.pipeline.inputs import ChannelGains, LampProfile, read_profile_csv, read_profile_file

COMMAND = (
    "rawproc-0.9.1Dev DSG_0001.NEF:rawdata=crop;  demosaic:half rotate:hmirror "
    "crop:0.000000,0.4,1.000000,0.5 "
)


def _dat_bytes(
    red: list[float],
    green: list[float],
    blue: list[float],
    *,
    height: int = 7,
    command: str = COMMAND,
) -> bytes:
    width = len(red)
    rows = [
        f"width: {width}",
        f"height: {height}",
        command,
        "x," + ",".join(str(k) for k in range(width)),
        *(
            f"{name}," + ",".join(f"{v:.6f}" for v in values)
            for name, values in (("red", red), ("green", green), ("blue", blue))
        ),
        "",
        *(
            f"{letter}max: {max(values):.6f} {letter}maxcolumn: {int(np.argmax(values))}"
            for letter, values in (("r", red), ("g", green), ("b", blue))
        ),
    ]
    return ("\n".join(rows) + "\n").encode()


RED = [0.000020, 0.000100, 0.020000, 0.150000, 0.010000]
GREEN = [0.000088, 0.050000, 0.159703, 0.030000, 0.000090]
BLUE = [0.097665, 0.040000, 0.001000, 0.000100, 0.000109]


def test_rawproc_dat_is_read_byte_for_byte(tmp_path: Path) -> None:
    path = tmp_path / "calibration.dat"
    path.write_bytes(_dat_bytes(RED, GREEN, BLUE))
    profile = read_rawproc_dat(path)
    np.testing.assert_array_equal(profile.pixel, np.arange(5.0))
    np.testing.assert_allclose(profile.profile, np.column_stack([RED, GREEN, BLUE]), atol=0)
    assert profile.profile_sigma is None
    assert profile.metadata["mirrored"] is True
    assert profile.metadata["rows_averaged"] == 7
    assert profile.metadata["command"] == COMMAND.strip()
    # The sensor's own column order undoes rawproc's hmirror.
    unmirrored = read_rawproc_dat(path, sensor_orientation=True)
    np.testing.assert_allclose(unmirrored.profile, profile.profile[::-1])
    observation = profile.to_observation(
        "CFL", Spectrum([380, 780], [1.0, 1.0]), kind="fluorescent"
    )
    assert observation.n_pixels == 5 and observation.kind == "fluorescent"
    assert observation.metadata["profile_file"] == str(path)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda text: text.replace("width: 5", "width: 6"), "has 5 values, width says 6"),
        (lambda text: text.replace("green,", "greem,"), "unexpected line"),
        (lambda text: text.replace("0.159703", "0.1x9703"), "is not a number"),
        (lambda text: text.replace("x,0,1,", "x,1,0,"), "x row must be 0, 1"),
        (lambda text: text.replace("gmax: 0.159703", "gmax: 0.200000"), "gmax 0.2 disagrees"),
        (lambda text: text.replace("red,", "red,nan,").replace("width: 5", "width: 6"), "NaN"),
        (lambda text: text.replace("height: 7\n", ""), "no height"),
    ],
)
def test_rawproc_dat_errors_name_the_file_and_line(tmp_path: Path, edit, message: str) -> None:
    path = tmp_path / "bad.dat"
    path.write_text(edit(_dat_bytes(RED, GREEN, BLUE).decode()))
    with pytest.raises(InputError, match=message) as caught:
        read_rawproc_dat(path)
    assert str(path) in str(caught.value)


def test_a_missing_dat_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="file not found"):
        read_rawproc_dat(tmp_path / "absent.dat")


def _fits_bytes(image: np.ndarray, cards: dict[str, object] | None = None) -> bytes:
    """A minimal FITS file written card by card (BITPIX −32, big-endian), as the standard says."""
    header = [
        ("SIMPLE", True),
        ("BITPIX", -32),
        ("NAXIS", image.ndim),
        *((f"NAXIS{k + 1}", n) for k, n in enumerate(reversed(image.shape))),
        *(cards or {}).items(),
    ]

    def card(key: str, value: object) -> bytes:
        if isinstance(value, bool):
            text = "T" if value else "F"
        elif isinstance(value, str):
            text = f"'{value:<8}'"
        else:
            text = str(value)
        return f"{key:<8}= {text:>20}".ljust(80).encode("ascii")

    block = b"".join(card(k, v) for k, v in header) + b"END".ljust(80)
    block += b" " * (-len(block) % 2880)
    data = struct.pack(f">{image.size}f", *image.astype(np.float32).ravel())
    return block + data + b"\0" * (-len(data) % 2880)


def _band_planes(rng: np.random.Generator, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Three planes (rows 12, columns 40): a band of rows 3–9 with a spectrum, plus noise."""
    columns = np.arange(40.0)
    spectra = np.stack(
        [np.exp(-0.5 * ((columns - centre) / 6.0) ** 2) for centre in (30.0, 20.0, 10.0)]
    )
    across = np.zeros(12)
    across[3:10] = [0.6, 0.9, 1.0, 1.0, 0.95, 0.85, 0.7]
    clean = across[None, :, None] * spectra[:, None, :]
    return clean + noise * rng.standard_normal(clean.shape), spectra


def _write_planes(folder: Path, seed: int, suffix: str = ".fit") -> list[Path]:
    """A band's R, G, B planes as three FITS files ``sun R{suffix}`` … in ``folder``."""
    planes, _ = _band_planes(np.random.default_rng(seed), 0.01)
    paths = []
    for name, plane in zip("RGB", planes, strict=True):
        paths.append(folder / f"sun {name}{suffix}")
        paths[-1].write_bytes(_fits_bytes(plane))
    return paths


def test_fits_planes_written_byte_by_byte_give_the_band_sum_with_sigma(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    noise = 0.01
    planes, spectra = _band_planes(rng, noise)
    paths = []
    for name, plane in zip("RGB", planes, strict=True):
        path = tmp_path / f"band {name}.fit"
        path.write_bytes(_fits_bytes(plane, {"EXPTIME": 0.25, "INSTRUME": "Twin"}))
        paths.append(path)
    profile = read_fits_profile(paths)
    assert profile.metadata["band_rows"] == [3, 10]
    assert profile.metadata["rows_summed"] == 7
    assert profile.metadata["header"]["EXPTIME"] == 0.25
    # Background: the 5 rows outside the band (their median per column) is subtracted.
    expected = 5.0 * spectra.T  # the across profile sums to 6.0, less nothing but noise
    np.testing.assert_allclose(profile.profile, expected * 6.0 / 5.0, atol=6 * noise * np.sqrt(7))
    assert profile.profile_sigma is not None
    # Independent rows: the σ of a sum of 7 rows is √7 × the per-row noise (within sampling).
    np.testing.assert_allclose(np.median(profile.profile_sigma), noise * np.sqrt(7), rtol=0.35)


def test_calib_estimate_reads_each_profile_format_by_its_suffix(tmp_path: Path) -> None:
    planes, _ = _band_planes(np.random.default_rng(6), 0.01)
    cube = tmp_path / "band.fits"
    cube.write_bytes(_fits_bytes(planes))
    dat = tmp_path / "band.dat"
    dat.write_bytes(_dat_bytes(RED, GREEN, BLUE))
    csv = tmp_path / "band.csv"
    csv.write_text("pixel,r,g,b\n" + "".join(f"{k},{k},{2 * k},{3 * k}\n" for k in range(9)))
    from_fits, from_dat = read_profile_file(cube), read_profile_file(dat)
    np.testing.assert_array_equal(from_fits.profile, read_fits_profile(cube).profile)
    np.testing.assert_array_equal(from_dat.profile, read_rawproc_dat(dat).profile)
    np.testing.assert_array_equal(from_dat.axis, read_rawproc_dat(dat).pixel)
    assert not from_fits.in_wavelength and not from_dat.in_wavelength
    assert from_dat.profile_sigma is None and from_fits.profile_sigma is not None
    np.testing.assert_array_equal(read_profile_file(csv).profile, read_profile_csv(csv).profile)


def test_a_profile_file_is_read_by_what_it_holds_and_the_fits_gains_warning_follows_the_reader(
    tmp_path: Path,
) -> None:
    """FITS planes named .dat are read as FITS and warned about as image planes; a CSV named .fit
    is read as a CSV, with no FITS warning (the warning comes from what was read, not the name)."""
    renamed = _write_planes(tmp_path, 11, ".dat")
    table = read_profile_file(tuple(renamed))
    np.testing.assert_array_equal(table.profile, read_fits_profile(renamed).profile)
    assert table.image_planes and table.profile_sigma is not None
    csv_named_fit = tmp_path / "band.fit"
    csv_named_fit.write_text(
        "pixel,r,g,b\n" + "".join(f"{k},{k},{2 * k},{3 * k}\n" for k in range(9))
    )
    from_csv = read_profile_file(csv_named_fit)
    np.testing.assert_array_equal(from_csv.profile, read_profile_csv(csv_named_fit).profile)
    assert not from_csv.image_planes
    for profile, warned in ((tuple(renamed), True), (csv_named_fit, False)):
        lamp = LampProfile("sun", "other", Path("D65"), profile)
        warnings = _check_inputs([lamp], OfflineSettings()).warnings
        said = [text for text in warnings if "--channel-gains unknown" in text]
        assert bool(said) is warned, warnings
    # Three files of which one is not FITS are refused, naming it.
    with pytest.raises(InputError, match=r"band\.fit: not FITS"):
        read_profile_file((renamed[0], renamed[1], csv_named_fit))


def test_fits_sigma_of_a_sum_of_correlated_rows(tmp_path: Path) -> None:
    rng = np.random.default_rng(9)
    rows, columns, sigma = 60, 40, 0.01
    spectrum = np.exp(-0.5 * ((np.arange(columns) - 20.0) / 6.0) ** 2)
    clean = np.broadcast_to(spectrum, (3, rows, columns))
    white = rng.standard_normal((3, rows + 1, columns)) * sigma
    cases = {
        # Neighbouring rows share a sample (as demosaicked rows do): var of the sum (4n − 2) σ².
        "correlated": (white[:, 1:, :] + white[:, :-1, :], np.sqrt(4 * rows - 2) * sigma),
        "independent": (white[:, 1:, :] * np.sqrt(2), np.sqrt(2 * rows) * sigma),
    }
    for name, (noise, expected) in cases.items():
        path = tmp_path / f"{name}.fits"
        path.write_bytes(_fits_bytes(clean + noise))
        profile = read_fits_profile(path)
        assert profile.profile_sigma is not None
        assert float(np.median(profile.profile_sigma)) == pytest.approx(expected, rel=0.15), name


def test_fits_errors_are_clear(tmp_path: Path) -> None:
    flat = tmp_path / "flat.fits"
    flat.write_bytes(_fits_bytes(np.ones((4, 6))))
    with pytest.raises(InputError, match="cube of 3 colour planes"):
        read_fits_planes(flat)
    other = tmp_path / "other.fits"
    other.write_bytes(_fits_bytes(np.ones((5, 6))))
    with pytest.raises(InputError, match="one shape"):
        read_fits_planes([flat, flat, other])
    with pytest.raises(InputError, match="three FITS files"):
        read_fits_planes([flat, flat])
    text = tmp_path / "text.fits"
    text.write_text("not a fits file")
    with pytest.raises(InputError, match="not a readable FITS file"):
        read_fits_planes(text)
    with pytest.raises(InputError, match="band rows"):
        read_fits_profile([flat, flat, flat], rows=(3, 4))


def test_fits_without_astropy_says_how_to_install(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import builtins

    real_import = builtins.__import__

    def no_astropy(name: str, *args: object, **kwargs: object) -> object:
        if name.startswith("astropy"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(builtins, "__import__", no_astropy)
    with pytest.raises(InputError, match=r"spectral-rig\[fits\]"):
        read_fits_planes(tmp_path / "any.fits")


@pytest.mark.shared_data
def test_the_d7000_rawproc_exports(shared_real_grating: Path) -> None:
    folder = shared_real_grating / "butcher-nikon-d7000-2020-08"
    cfl = read_rawproc_dat(folder / "D7000_calibration.dat")
    halogen = read_rawproc_dat(folder / "D7000_spectrum.dat")
    for name, profile in (("D7000_calibration.dat", cfl), ("D7000_spectrum.dat", halogen)):
        assert profile.profile.shape == (2474, 3)
        assert profile.metadata["mirrored"] is True and profile.metadata["rows_averaged"] == 115
        # The command is read, and a raw export's passes: nothing warned, undone or unknown.
        rawproc = profile.metadata["rawproc"]
        assert rawproc["input_options"] == {"rawdata": "crop"}
        assert [op["name"] for op in rawproc["operations"]] == ["demosaic", "rotate", "crop"]
        assert {finding["effect"] for finding in rawproc["findings"]} == {"keeps"}
        assert profile.warnings == () and profile.notes == ()
        assert profile.channel_gains_unknown is None
        # The same profile as the file's rows, value for value (no scaling).
        rows = {
            line.split(",", 1)[0]: np.array(line.split(",")[1:], dtype=float)
            for line in (folder / name).read_text().splitlines()
            if line.startswith(("red,", "green,", "blue,"))
        }
        np.testing.assert_array_equal(
            profile.profile, np.column_stack([rows["red"], rows["green"], rows["blue"]])
        )
    # In the file's (mirrored) order blue peaks first and red last: wavelength rises with x.
    peaks = cfl.profile.argmax(axis=0)
    assert peaks[2] < peaks[1] < peaks[0]
    assert tuple(peaks) == (1735, 1278, 546)  # the file's own rmaxcolumn/gmaxcolumn/bmaxcolumn


@pytest.mark.shared_data
def test_the_canon_10d_fits_planes(shared_real_grating: Path) -> None:
    folder = shared_real_grating / "rrogge-canon-eos-10d"
    paths = [folder / f"Solar Spectrum Canon EOS 10D {c}.fit" for c in "RGB"]
    profile = read_fits_profile(paths)
    assert profile.profile.shape == (1658, 3)
    assert profile.metadata["band_rows"] == [0, 128]  # the crop is all band
    assert profile.profile_sigma is not None and np.all(profile.profile_sigma > 0)
    # Demosaicked planes: neighbouring rows are correlated, and σ is inflated for it.
    assert all(factor > 1.5 for factor in profile.metadata["row_correlation_inflation"])
    peaks = profile.profile.argmax(axis=0)
    assert peaks[2] < peaks[1] < peaks[0]
    snr = profile.profile / profile.profile_sigma
    assert 100 < float(np.max(snr)) < 5000


def test_calib_estimate_reads_the_planes_as_three_files_and_nothing_else(tmp_path: Path) -> None:
    """A FITS export's R, G, B planes as three files (the real Canon 10D data come so): the same
    profile as the reader's; two files, or three that are not FITS, are refused naming them."""
    paths = _write_planes(tmp_path, 7)
    table = read_profile_file(tuple(paths))
    np.testing.assert_array_equal(table.profile, read_fits_profile(paths).profile)
    assert not table.in_wavelength
    with pytest.raises(InputError, match="2 files: a profile is one file") as refused:
        read_profile_file(tuple(paths[:2]))
    assert "sun R.fit" in str(refused.value) and "sun G.fit" in str(refused.value)
    csvs = tuple(tmp_path / f"{c}.csv" for c in "rgb")
    with pytest.raises(InputError, match="R, G and B planes of a FITS export"):
        read_profile_file(csvs)


@pytest.mark.parametrize(("gains", "warned"), [("raw", True), ("unknown", False)])
def test_fits_planes_taken_with_raw_gains_are_warned(
    tmp_path: Path, gains: ChannelGains, warned: bool
) -> None:
    """FITS R, G, B planes are an RGB image's: taken as raw when a conversion balanced them, the
    channels' balance is silently wrong (the real Canon 10D's by 30 % of the peak), so the
    estimate says how to declare them unless the user did."""
    paths = _write_planes(tmp_path, 8)
    lamp = LampProfile("sun", "other", Path("D65"), tuple(paths), channel_gains=gains)
    warnings = _check_inputs([lamp], OfflineSettings()).warnings
    said = [text for text in warnings if "--channel-gains unknown" in text]
    assert bool(said) is warned, warnings


# ------------------------------------------------------------------------- the rawproc command


def _command(*operations: str, source: str = "DSG_0001.NEF:rawdata=crop;") -> str:
    return " ".join(["rawproc-0.9.1Dev", source, "demosaic:half", *operations, "crop:0,0.4,1,0.5"])


def _write_dat(path: Path, command: str, scale: tuple[float, float, float] = (1, 1, 1)) -> Path:
    red, green, blue = (
        [v * k for v in values] for values, k in zip((RED, GREEN, BLUE), scale, strict=True)
    )
    path.write_bytes(_dat_bytes(red, green, blue, command=command))
    return path


def test_the_rawproc_command_is_read_into_its_input_and_operations() -> None:
    command = parse_rawproc_command(
        "rawproc-0.9.1Dev DSG_4683.NEF:rawdata=crop;  demosaic:half rotate:hmirror "
        'whitebalance:{"mode": "camera"} crop:0.000000,0.427027,1.000000,0.497297 '
    )
    assert command.program == "rawproc-0.9.1Dev" and command.input_file == "DSG_4683.NEF"
    assert command.input_options == {"rawdata": "crop"}
    assert [op.label for op in command.operations] == [
        "demosaic:half",
        "rotate:hmirror",
        'whitebalance:{"mode": "camera"}',  # a JSON block kept whole across its space
        "crop:0.000000,0.427027,1.000000,0.497297",
    ]
    assert command.operations[2].named() == {"mode": "camera"}
    assert command.operations[3].positional()[1] == "0.427027"


@pytest.mark.parametrize(
    ("operation", "source"),
    [
        ("gamma:2.2", "DSG_0001.NEF:rawdata=crop;"),
        ("tone:filmic", "DSG_0001.NEF:rawdata=crop;"),
        ("curve:rgb,0,0,128,160,255,255", "DSG_0001.NEF:rawdata=crop;"),
        ("saturation:1.3", "DSG_0001.NEF:rawdata=crop;"),
        ("colorspace:srgb,convert,perceptual", "DSG_0001.NEF:rawdata=crop;"),
        ("gray", "DSG_0001.NEF:rawdata=crop;"),
        ("hlrecover", "DSG_0001.NEF:rawdata=crop;"),
        ("whitebalance:bluethreshold,2,1,1.5,0.2", "DSG_0001.NEF:rawdata=crop;"),
        ("input DSG_0001.jpg", "DSG_0001.jpg"),
    ],
)
def test_a_non_linear_or_channel_mixing_rawproc_command_is_refused_naming_file_and_operation(
    tmp_path: Path, operation: str, source: str
) -> None:
    command = _command(*([] if operation.startswith("input") else [operation]), source=source)
    path = _write_dat(tmp_path / "D7000.dat", command)
    with pytest.raises(InputError) as refused:
        read_rawproc_dat(path)
    message = str(refused.value)
    assert message.startswith(f"{path}: the rawproc command applies {operation}, which "), message
    assert "export the data again without it" in message and "\n" not in message
    with pytest.raises(InputError, match="applies"):
        read_profile_file(path)


@pytest.mark.parametrize(
    "operation",
    [
        "gamma:1.0",
        "tone:gamma,1",
        "curve:rgb,0,0,255,255",
        "colorspace:camera,assign",
        "exposure:0.5",
        "subtract:dark.tif",
        "blackwhitepoint:rgb,0,255",
        "rotate:1.5",
        "denoise:nlmeans,1",
    ],
)
def test_a_linear_rawproc_operation_passes_and_is_listed(tmp_path: Path, operation: str) -> None:
    path = _write_dat(tmp_path / "band.dat", _command(operation))
    profile = read_rawproc_dat(path)
    np.testing.assert_array_equal(profile.profile, np.column_stack([RED, GREEN, BLUE]))
    assert profile.warnings == () and profile.notes == () and profile.channel_gains_unknown is None
    findings = {
        item["operation"]: item["effect"] for item in profile.metadata["rawproc"]["findings"]
    }
    assert findings[operation] == "keeps"


@pytest.mark.parametrize(
    ("operations", "multipliers"),
    [
        (["whitebalance:2,1,4"], (2.0, 1.0, 4.0)),
        (
            ["whitebalance:mode=multipliers;redmultiplier=4;greenmultiplier=1;bluemultiplier=2"],
            (4.0, 1.0, 2.0),
        ),
        (["whitebalance:2,1,1", "exposure:1", "whitebalance:1,1,4"], (2.0, 1.0, 4.0)),
    ],
)
def test_stated_white_balance_multipliers_are_undone_to_the_raw_values(
    tmp_path: Path, operations: list[str], multipliers: tuple[float, float, float]
) -> None:
    path = _write_dat(tmp_path / "balanced.dat", _command(*operations), scale=multipliers)
    profile = read_rawproc_dat(path)
    # Powers of two: the division is exact, so the raw values come back bit for bit.
    np.testing.assert_array_equal(profile.profile, np.column_stack([RED, GREEN, BLUE]))
    assert profile.metadata["rawproc"]["undone_multipliers"] == list(multipliers)
    assert profile.channel_gains_unknown is None and profile.warnings == ()
    (note,) = profile.notes
    assert "balanced.dat" in note and operations[0] in note and "divided out" in note
    assert "channel_gains" not in profile.to_observation("A", Spectrum([380, 780], [1, 1])).metadata


@pytest.mark.parametrize(
    ("operation", "source", "said"),
    [
        ("whitebalance:camera", "DSG_0001.NEF:rawdata=crop;", "as-shot multipliers"),
        ("whitebalance:auto", "DSG_0001.NEF:rawdata=crop;", "gray-world"),
        ("blackwhitepoint:red,0,200", "DSG_0001.NEF:rawdata=crop;", "red channel's black"),
        ("", "DSG_0001.NEF", "opened without rawdata=crop"),
    ],
)
@pytest.mark.parametrize("gains", ["raw", "unknown"])
def test_unstated_channel_gains_are_taken_as_unknown_with_a_warning(
    tmp_path: Path, operation: str, source: str, said: str, gains: ChannelGains
) -> None:
    """A file that says its gains are not raw overrides the default "raw", warning why; the user
    who already said "unknown" hears nothing more."""
    path = _write_dat(tmp_path / "wb.dat", _command(*filter(None, [operation]), source=source))
    profile = read_rawproc_dat(path)
    assert profile.channel_gains_unknown is not None and said in profile.channel_gains_unknown
    np.testing.assert_array_equal(profile.profile, np.column_stack([RED, GREEN, BLUE]))
    observation = profile.to_observation("A", Spectrum([380, 780], [1, 1]))
    assert observation.metadata["channel_gains"] == "unknown"
    lamp = LampProfile("sun", "other", Path("D65"), path, channel_gains=gains)
    checked = _check_inputs([lamp], OfflineSettings())
    assert checked.channel_gains == {"sun": "unknown"}
    said_lines = [line for line in checked.warnings if "channel gains unknown" in line]
    if gains == "raw":
        (line,) = said_lines
        assert line.startswith("lamp 'sun': the rawproc command's ") and said in line, line
    else:
        assert said_lines == [], checked.warnings


@pytest.mark.parametrize("operation", ["frobnicate:3", "group:steps.txt", "gmic:blur.gmic"])
def test_an_operation_that_cannot_be_checked_is_warned_and_the_data_kept(
    tmp_path: Path, operation: str
) -> None:
    path = _write_dat(tmp_path / "odd.dat", _command(operation))
    profile = read_rawproc_dat(path)
    np.testing.assert_array_equal(profile.profile, np.column_stack([RED, GREEN, BLUE]))
    (warning,) = profile.warnings
    assert warning.startswith(f"odd.dat: the rawproc command's {operation} "), warning
    lamp = LampProfile("sun", "other", Path("D65"), path)
    assert warning in _check_inputs([lamp], OfflineSettings()).warnings


@pytest.mark.parametrize(
    ("operations", "reversed_columns"),
    [
        (["rotate:hmirror"], True),
        (["rotate:180"], True),
        (["rotate:angle=180"], True),
        (['rotate:{"hmirror": "true"}'], True),
        (["rotate:vmirror"], False),
        (["rotate:1.5"], False),
        (["rotate:hmirror", "rotate:vmirror"], True),
        (["rotate:hmirror", "rotate:hmirror"], False),
        (["rotate:hmirror", "rotate:180"], False),
        (["rotate:90", "rotate:90"], True),
        (["rotate:90", "rotate:270"], False),
    ],
)
def test_every_rotation_that_reverses_the_columns_is_undone_and_two_reversals_cancel(
    tmp_path: Path, operations: list[str], reversed_columns: bool
) -> None:
    """rawproc's rotate takes hmirror, vmirror and angles: a half turn reverses the columns as a
    hmirror does, a vmirror only the rows (which a column mean ignores)."""
    path = _write_dat(tmp_path / "turned.dat", _command(*operations))
    as_filed = read_rawproc_dat(path)
    as_sensor = read_rawproc_dat(path, sensor_orientation=True)
    assert as_filed.metadata["mirrored"] is reversed_columns
    assert as_filed.warnings == () and as_sensor.warnings == ()
    np.testing.assert_array_equal(as_filed.profile, np.column_stack([RED, GREEN, BLUE]))
    expected = as_filed.profile[::-1] if reversed_columns else as_filed.profile
    np.testing.assert_array_equal(as_sensor.profile, expected)
    assert as_sensor.metadata["pixel_axis"] == "sensor columns of the crop"


@pytest.mark.parametrize("operations", [["rotate:90"], ["rotate:270"], ["rotate:angle=90"]])
def test_a_quarter_turn_is_warned_and_refused_for_the_sensor_order(
    tmp_path: Path, operations: list[str]
) -> None:
    """After a quarter turn the file's columns are the sensor's rows: read in the file's order with
    a warning naming the step; no sensor column order to restore, so that is refused in one line."""
    path = _write_dat(tmp_path / "quarter.dat", _command(*operations))
    profile = read_rawproc_dat(path)
    np.testing.assert_array_equal(profile.profile, np.column_stack([RED, GREEN, BLUE]))
    (warning,) = profile.warnings
    assert warning.startswith(f"quarter.dat: the rawproc command's {operations[0]} "), warning
    assert "quarter turn" in warning and profile.metadata["quarter_turn"] is True
    with pytest.raises(InputError) as refused:
        read_rawproc_dat(path, sensor_orientation=True)
    message = str(refused.value)
    assert message.startswith(f"{path}: the rawproc command's {operations[0]} "), message
    assert "\n" not in message


@pytest.mark.parametrize(
    ("line", "input_file", "options", "labels"),
    [
        (
            "rawproc-0.9.1Dev My Shot 01.NEF:rawdata=crop;  demosaic:half rotate:hmirror crop:0,1",
            "My Shot 01.NEF",
            {"rawdata": "crop"},
            ["demosaic:half", "rotate:hmirror", "crop:0,1"],
        ),
        (
            "rawproc-0.9.1Dev My crop v1.2 shot.NEF:rawdata=crop; demosaic:half",
            "My crop v1.2 shot.NEF",
            {"rawdata": "crop"},
            ["demosaic:half"],
        ),
        (
            "rawproc-0.9 My Shot.NEF demosaic:half rotate:180",
            "My Shot.NEF",
            {},
            ["demosaic:half", "rotate:180"],
        ),
        (
            r"rawproc-img C:\raw\My Shot.NEF:rawdata=1 demosaic:half",
            r"C:\raw\My Shot.NEF",
            {"rawdata": "1"},
            ["demosaic:half"],
        ),
    ],
)
def test_an_input_file_name_with_spaces_is_read_whole(
    line: str, input_file: str, options: dict[str, str], labels: list[str]
) -> None:
    command = parse_rawproc_command(line)
    assert command.input_file == input_file and command.input_options == options
    assert [op.label for op in command.operations] == labels
    assert command.parse_warning is None


def test_a_dat_whose_input_has_spaces_reads_as_raw_and_one_whose_input_cannot_be_told_is_warned(
    tmp_path: Path,
) -> None:
    path = _write_dat(
        tmp_path / "spaced.dat", _command("rotate:180", source="My Shot 01.NEF:rawdata=crop;")
    )
    profile = read_rawproc_dat(path)
    assert profile.warnings == () and profile.channel_gains_unknown is None
    assert profile.metadata["rawproc"]["input_file"] == "My Shot 01.NEF"
    assert profile.metadata["mirrored"] is True
    # No word ends in an extension: the name cannot be told from the tools, and that is said.
    path = _write_dat(tmp_path / "odd.dat", _command(source="shot one:rawdata=crop;"))
    profile = read_rawproc_dat(path)
    assert any(
        text.startswith("odd.dat: where the rawproc command's input 'shot' ends cannot be told")
        for text in profile.warnings
    ), profile.warnings


def test_every_tool_the_input_name_ends_before_is_one_the_reader_judges() -> None:
    # The list that ends an input's name with spaces and the tools judged are one list: a tool
    # added to one and not the other fails here.
    from calib.image.profile_files import _RAWPROC_TOOLS, RawprocOperation, _operation_finding

    unknown = "is not a rawproc tool this reader knows"
    assert all(
        _operation_finding(RawprocOperation(name, "")).reason != unknown for name in _RAWPROC_TOOLS
    )
    assert _operation_finding(RawprocOperation("frobnicate", "")).reason == unknown
    command = parse_rawproc_command("rawproc-0.9 My Shot.NEF gamma:1.0 tone:gamma,1.0")
    assert command.input_file == "My Shot.NEF"
    assert [op.name for op in command.operations] == ["gamma", "tone"]
