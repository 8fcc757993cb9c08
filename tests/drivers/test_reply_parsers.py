"""Every reply parser raises only typed errors, whatever the instrument sends.

Hypothesis examples over random bytes and over valid replies with a few bytes replaced, inserted
or deleted (the realistic kind of damage), for the serial instruments' parsers (PR-6xx, CS-2000,
LCUS, Numato), the HID relay driver fed damaged control-transfer replies, and the camera driver fed
damaged widget choices and values. A few hundred examples each in the default suite; the ``_slow``
variants (``make test-all``) run the numbers in :func:`tests.fuzzing.fuzz`.

The typed errors are :class:`drivers.base.DeviceError` and its subclasses; the camera's pure
matching helpers document ``ValueError`` (the driver turns it into ``SettingValueError``).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator

from hypothesis import strategies as st

from drivers.base import DeviceError
from drivers.camera import ExposureTable, open_camera, parse_exposure_s
from drivers.camera.choices import match_choice
from drivers.relays import lcus, numato
from drivers.relays.hid_usbrelay import open_hid_relay
from drivers.replies import ReplyContext, decode_ascii, parse_float, parse_int
from drivers.spectrometer import cs2000, pr6xx
from mocks.fake_gphoto2 import FakeBody, FakeGphoto2, WidgetSpec
from mocks.fake_gphoto2.constants import GP_WIDGET_RADIO, GP_WIDGET_TOGGLE
from mocks.usb_relay_backend import EmulatedRelayBoard, FakeUsbBackend
from tests.fuzzing import fuzz

CONTEXT = ReplyContext("fuzzed device", "command")

VALID_REPLIES = [
    b"00000,PR-655\r\n",
    b"00000,101,0.00,380,780,4,256,7,247\r\n",
    b"00000,0,5.560e+02,1.827e-01,5.147e+01\r\n",
    b"00000,Normal,250 msec\r\n",
    b"-1010\r\n",
    b"OK00,CS-2000  ,1,1000123\n",
    b"OK00,003\n",
    b"OK00,3,000250000,2\n",
    b"OK00,0,0,000250000,2,0,0,0,0\n",
    b"OK00,3A78DCC7,3A71B62F,3A67C358\n",
    b"ER02\n",
    b"CH1: ON \r\nCH2: OFF\r\n",
    b"relay readall\n\r0F\n\r>",
    b"relay read 0\r\non\r\n>",
]
#: Control-transfer replies of a dcttech board: language ids, its two strings, a feature report.
VALID_USB_REPLIES = [
    bytes([4, 3, 0x09, 0x04]),
    bytes([32, 3]) + "www.dcttech.com".encode("utf-16-le"),
    bytes([20, 3]) + "USBRelay2".encode("utf-16-le"),
    b"FUZZ1\x00\x00\x01",
    b"FUZZ1\x00\x00\x00",
]
EXPOSURE_TEXTS = ["1/125", "0.3", "30", '1"', "bulb", "Bulb", "0.0100s", "1/8000", "2.5", "Time"]
CHOICE_TEXTS = ["f/5.6", "5.6", "Auto", "100", "RAW", "NEF (Raw)", "Large Fine JPEG", "sRAW"]


def _damage(draw: st.DrawFn, valid: bytes) -> bytes:
    reply = bytearray(valid)
    for _ in range(draw(st.integers(1, 3))):
        position = draw(st.integers(0, len(reply)))
        removed = draw(st.integers(0, 2))
        reply[position : position + removed] = draw(st.binary(max_size=2))
    return bytes(reply)


@st.composite
def damaged(draw: st.DrawFn) -> bytes:
    """A valid reply with a few bytes replaced, inserted or deleted."""
    return _damage(draw, draw(st.sampled_from(VALID_REPLIES)))


@st.composite
def usb_replies(draw: st.DrawFn) -> list[bytes]:
    """The board's replies in the order the driver asks, each valid, damaged or random."""
    replies = []
    for valid in [*VALID_USB_REPLIES[:3], *([VALID_USB_REPLIES[3]] * 4)]:
        kind = draw(st.sampled_from(["valid", "valid", "damaged", "random"]))
        if kind == "valid":
            replies.append(valid)
        elif kind == "damaged":
            replies.append(_damage(draw, valid))
        else:
            replies.append(draw(st.binary(max_size=40)))
    return replies


replies = st.one_of(st.binary(max_size=120), damaged())
fields = st.lists(
    st.one_of(st.text(max_size=10), st.from_regex(r"[0-9A-F]{8}", fullmatch=True)),
    max_size=8,
)
texts = st.one_of(st.text(max_size=12), st.sampled_from(EXPOSURE_TEXTS + CHOICE_TEXTS))
choice_lists = st.lists(texts, max_size=6)


def typed_errors_only(
    parse: Callable[[], object], typed: tuple[type[Exception], ...] = (DeviceError,)
) -> None:
    """Run ``parse``; a typed error is fine, anything else fails the test."""
    with contextlib.suppress(*typed):
        parse()


# ------------------------------------------------------------------------------- serial parsers


def _text_helpers(reply: bytes) -> None:
    typed_errors_only(lambda: decode_ascii(reply, CONTEXT))
    text = reply.decode("latin-1")
    typed_errors_only(lambda: parse_int(text, "number", CONTEXT, reply))
    typed_errors_only(lambda: parse_float(text, "number", CONTEXT, reply))


test_text_helpers, test_text_helpers_slow = fuzz(10_000, reply=replies)(_text_helpers)


def _pr6xx_parsers(reply: bytes, data_fields: list[str]) -> None:
    typed_errors_only(lambda: pr6xx.parse_reply_line(reply, CONTEXT))
    typed_errors_only(lambda: pr6xx.parse_status_reply(reply, CONTEXT))
    typed_errors_only(lambda: pr6xx.parse_grid(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: pr6xx.parse_spectrum_header(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: pr6xx.parse_exposure_report(data_fields, CONTEXT, reply))


test_pr6xx_parsers, test_pr6xx_parsers_slow = fuzz(10_000, reply=replies, data_fields=fields)(
    _pr6xx_parsers
)


def _pr6xx_spectrum_parser(header: bytes, lines: list[bytes]) -> None:
    grid = pr6xx.SpectralGrid(points=3, start_nm=380.0, stop_nm=388.0, step_nm=4.0)
    typed_errors_only(lambda: pr6xx.parse_spectrum(header, lines, grid, CONTEXT))


test_pr6xx_spectrum_parser, test_pr6xx_spectrum_parser_slow = fuzz(
    10_000, header=replies, lines=st.lists(replies, min_size=3, max_size=3)
)(_pr6xx_spectrum_parser)


def _cs2000_parsers(reply: bytes, data_fields: list[str], block: int) -> None:
    typed_errors_only(lambda: cs2000.parse_reply(reply, CONTEXT))
    typed_errors_only(lambda: cs2000.parse_identity(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: cs2000.parse_measurement_time(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: cs2000.parse_conditions(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: cs2000.parse_speed_setting(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: cs2000.parse_spectral_block(data_fields, block, CONTEXT, reply))


test_cs2000_parsers, test_cs2000_parsers_slow = fuzz(
    10_000,
    reply=replies,
    data_fields=fields,
    block=st.sampled_from(sorted(cs2000.SPECTRAL_BLOCKS)),
)(_cs2000_parsers)


def _cs2000_blocks_of_any_hex(hex_fields: list[str]) -> None:
    """Any 8-digit hex decodes or is refused as non-finite / not calculable, never anything else."""
    typed_errors_only(lambda: cs2000.parse_spectral_block(hex_fields, 1, CONTEXT, b""))


test_cs2000_blocks_of_any_hex, test_cs2000_blocks_of_any_hex_slow = fuzz(
    5_000,
    hex_fields=st.lists(
        st.integers(0, 2**32 - 1).map(lambda word: f"{word:08X}"), min_size=100, max_size=100
    ),
)(_cs2000_blocks_of_any_hex)


def _relay_parsers(reply: bytes, lines: list[str], channels: int) -> None:
    typed_errors_only(lambda: lcus.parse_status(reply, channels, CONTEXT))
    typed_errors_only(lambda: numato.parse_reply(reply, "relay readall", CONTEXT))
    typed_errors_only(lambda: numato.parse_reply(reply, "", CONTEXT))
    typed_errors_only(lambda: numato.parse_mask(lines, channels, CONTEXT))
    typed_errors_only(lambda: numato.parse_relay_read(lines, CONTEXT))


test_relay_parsers, test_relay_parsers_slow = fuzz(
    10_000,
    reply=replies,
    lines=st.lists(st.text(max_size=10), max_size=3),
    channels=st.sampled_from([1, 2, 4, 8]),
)(_relay_parsers)


# ------------------------------------------------------------------------------- HID relay


class _FuzzedBoard(EmulatedRelayBoard):
    """A board whose string descriptors and feature reports are the drawn replies, in order."""

    def __init__(self, answers: list[bytes]) -> None:
        super().__init__("FUZZ1", 2)
        self._answers: Iterator[bytes] = iter(answers)

    def string_descriptor(self, index: int) -> bytes | None:
        return next(self._answers, None)

    def feature_report(self) -> bytes:
        return next(self._answers, b"")


def _hid_relay_replies(answers: list[bytes]) -> None:
    try:
        board = open_hid_relay(None, backend=FakeUsbBackend([_FuzzedBoard(answers)]))
    except DeviceError:
        return
    try:
        typed_errors_only(lambda: board.set(1, True))
        typed_errors_only(board.state)
        typed_errors_only(board.all_off)
    finally:
        board.close()


test_hid_relay_replies, test_hid_relay_replies_slow = fuzz(10_000, answers=usb_replies())(
    _hid_relay_replies
)


# ------------------------------------------------------------------------------- camera


def _exposure_and_choice_parsing(text: str, choices: list[str], exposure_s: float) -> None:
    seconds = None
    with contextlib.suppress(ValueError):
        seconds = parse_exposure_s(text)
    assert seconds is None or (seconds > 0 and math.isfinite(seconds))
    table = ExposureTable.from_choices(choices)
    typed_errors_only(lambda: table.nearest(exposure_s), (ValueError,))
    typed_errors_only(lambda: (table.shortest_s, table.longest_s), (ValueError,))
    for kind in ("aperture", "iso", "imageformat", "capturetarget", "generic"):
        typed_errors_only(lambda kind=kind: match_choice(kind, text, choices), (ValueError,))  # type: ignore[misc]


exposures = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(1e-5, 1e4))
test_exposure_and_choice_parsing, test_exposure_and_choice_parsing_slow = fuzz(
    10_000, text=texts, choices=choice_lists, exposure_s=exposures
)(_exposure_and_choice_parsing)


def _radio(name: str, choices: list[str], value: str) -> WidgetSpec:
    return WidgetSpec(name, name, GP_WIDGET_RADIO, "capturesettings", value, tuple(choices))


def _camera_settings(
    shutter: list[str], aperture: list[str], iso: list[str], requests: list[str], exposure_s: float
) -> None:
    widgets = [
        _radio("shutterspeed", shutter, shutter[0] if shutter else ""),
        _radio("f-number", aperture, aperture[0] if aperture else ""),
        _radio("iso", iso, iso[0] if iso else ""),
        WidgetSpec("bulb", "Bulb", GP_WIDGET_TOGGLE, "actions", 0),
    ]
    body = FakeBody("Fuzz Cam", "usb:001,002", widgets)
    camera = open_camera(gphoto2_module=FakeGphoto2([body]), capture_target=None)
    try:
        typed_errors_only(camera.exposure_range_s)
        typed_errors_only(lambda: camera.set_exposure(exposure_s))
        for name, value in zip(["shutterspeed", "aperture", "iso"], requests, strict=False):
            typed_errors_only(lambda name=name, value=value: camera.set_setting(name, value))  # type: ignore[misc]
    finally:
        camera.close()


test_camera_settings, test_camera_settings_slow = fuzz(
    5_000,
    shutter=choice_lists.map(lambda c: list(dict.fromkeys(c))),
    aperture=choice_lists.map(lambda c: list(dict.fromkeys(c))),
    iso=choice_lists.map(lambda c: list(dict.fromkeys(c))),
    requests=st.lists(texts, max_size=3),
    exposure_s=exposures,
)(_camera_settings)
