"""Every reply parser raises only typed device errors, whatever bytes the instrument sends.

A modest number of hypothesis examples per parser, over random bytes and over valid replies with a
few bytes replaced, inserted or deleted (the realistic kind of damage).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.base import DeviceError
from drivers.relays import lcus, numato
from drivers.replies import ReplyContext, decode_ascii, parse_float, parse_int
from drivers.spectrometer import cs2000, pr6xx

CONTEXT = ReplyContext("fuzzed device", "command")
EXAMPLES = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])

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


@st.composite
def damaged(draw: st.DrawFn) -> bytes:
    """A valid reply with a few bytes replaced, inserted or deleted."""
    reply = bytearray(draw(st.sampled_from(VALID_REPLIES)))
    for _ in range(draw(st.integers(1, 3))):
        position = draw(st.integers(0, len(reply)))
        removed = draw(st.integers(0, 2))
        inserted = draw(st.binary(max_size=2))
        reply[position : position + removed] = inserted
    return bytes(reply)


replies = st.one_of(st.binary(max_size=120), damaged())
fields = st.lists(
    st.one_of(st.text(max_size=10), st.from_regex(r"[0-9A-F]{8}", fullmatch=True)),
    max_size=8,
)


def typed_errors_only(parse: Callable[[], object]) -> None:
    """Run ``parse``; a typed device error is fine, anything else fails the test."""
    with contextlib.suppress(DeviceError):
        parse()


@EXAMPLES
@given(reply=replies)
def test_text_helpers(reply: bytes) -> None:
    typed_errors_only(lambda: decode_ascii(reply, CONTEXT))
    text = reply.decode("latin-1")
    typed_errors_only(lambda: parse_int(text, "number", CONTEXT, reply))
    typed_errors_only(lambda: parse_float(text, "number", CONTEXT, reply))


@EXAMPLES
@given(reply=replies, data_fields=fields)
def test_pr6xx_parsers(reply: bytes, data_fields: list[str]) -> None:
    typed_errors_only(lambda: pr6xx.parse_reply_line(reply, CONTEXT))
    typed_errors_only(lambda: pr6xx.parse_status_reply(reply, CONTEXT))
    typed_errors_only(lambda: pr6xx.parse_grid(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: pr6xx.parse_spectrum_header(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: pr6xx.parse_exposure_report(data_fields, CONTEXT, reply))


@EXAMPLES
@given(header=replies, lines=st.lists(replies, min_size=3, max_size=3))
def test_pr6xx_spectrum_parser(header: bytes, lines: list[bytes]) -> None:
    grid = pr6xx.SpectralGrid(points=3, start_nm=380.0, stop_nm=388.0, step_nm=4.0)
    typed_errors_only(lambda: pr6xx.parse_spectrum(header, lines, grid, CONTEXT))


@EXAMPLES
@given(reply=replies, data_fields=fields, block=st.sampled_from(sorted(cs2000.SPECTRAL_BLOCKS)))
def test_cs2000_parsers(reply: bytes, data_fields: list[str], block: int) -> None:
    typed_errors_only(lambda: cs2000.parse_reply(reply, CONTEXT))
    typed_errors_only(lambda: cs2000.parse_identity(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: cs2000.parse_measurement_time(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: cs2000.parse_conditions(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: cs2000.parse_speed_setting(data_fields, CONTEXT, reply))
    typed_errors_only(lambda: cs2000.parse_spectral_block(data_fields, block, CONTEXT, reply))


@EXAMPLES
@given(
    hex_fields=st.lists(
        st.integers(0, 2**32 - 1).map(lambda word: f"{word:08X}"), min_size=100, max_size=100
    )
)
def test_cs2000_blocks_of_any_hex(hex_fields: list[str]) -> None:
    """Any 8-digit hex decodes or is refused as non-finite / not calculable, never anything else."""
    typed_errors_only(lambda: cs2000.parse_spectral_block(hex_fields, 1, CONTEXT, b""))


@EXAMPLES
@given(
    reply=replies,
    lines=st.lists(st.text(max_size=10), max_size=3),
    channels=st.sampled_from([1, 2, 4, 8]),
)
def test_relay_parsers(reply: bytes, lines: list[str], channels: int) -> None:
    typed_errors_only(lambda: lcus.parse_status(reply, channels, CONTEXT))
    typed_errors_only(lambda: numato.parse_reply(reply, "relay readall", CONTEXT))
    typed_errors_only(lambda: numato.parse_reply(reply, "", CONTEXT))
    typed_errors_only(lambda: numato.parse_mask(lines, channels, CONTEXT))
    typed_errors_only(lambda: numato.parse_relay_read(lines, CONTEXT))
