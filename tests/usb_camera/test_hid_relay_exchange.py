"""Exact-exchange tests of every HID USBRelay command: the control transfers, byte for byte."""

from __future__ import annotations

import errno
import json

import pytest
import usb.core

from drivers.base import (
    DeviceBusy,
    DeviceError,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    ListTranscript,
    ProtocolError,
    StateMismatch,
)
from drivers.relays.hid_usbrelay import (
    FeatureReport,
    HidUsbRelay,
    channel_count_from_product,
    command_report,
    decode_string_descriptor,
    open_hid_relay,
    setup_packet,
)
from mocks.usb_relay_backend import device_descriptor
from tests.usb_camera.usb_exchange import Transfer, expected_transfers, string_descriptor

SERIAL = b"QAAMZ"


def get_report(state: int, serial: bytes = SERIAL, request_type: int = 0xA0) -> Transfer:
    """HID GET_REPORT (Feature, report 0) on interface 0, 8 bytes: ID, two zeros, bitmask."""
    return Transfer(
        request_type, 0x01, 0x0300, 0, length=8, reply=serial + b"\x00\x00" + bytes([state])
    )


def set_report(payload: str, request_type: int = 0x20) -> Transfer:
    """HID SET_REPORT (Feature, report 0) with an 8-byte payload given in hex."""
    return Transfer(request_type, 0x09, 0x0300, 0, data=bytes.fromhex(payload))


def open_script(
    product: str = "USBRelay2",
    state: int = 0,
    manufacturer: str = "www.dcttech.com",
    request_type: int = 0xA0,
) -> list[Transfer]:
    """What opening a board sends: LANGID list, manufacturer, product, then the feature report."""
    return [
        Transfer(0x80, 0x06, 0x0300, 0x0000, length=254, reply=bytes.fromhex("04030904")),
        Transfer(0x80, 0x06, 0x0301, 0x0409, length=254, reply=string_descriptor(manufacturer)),
        Transfer(0x80, 0x06, 0x0302, 0x0409, length=254, reply=string_descriptor(product)),
        get_report(state, request_type=request_type),
    ]


def usb_error(errno_value: int, text: str, timeout: bool = False) -> usb.core.USBError:
    cls = usb.core.USBTimeoutError if timeout else usb.core.USBError
    return cls(text, None, errno_value)


# ----------------------------------------------------------------------------------- commands


def test_open_reads_strings_serial_and_state() -> None:
    transcript = ListTranscript()
    with expected_transfers(open_script("USBRelay4", state=0b0101)) as backend:
        relay = open_hid_relay(None, backend=backend, transcript=transcript)
        assert relay.channels == 4
        assert relay.serial == "QAAMZ"
        identity = relay.identify()
        assert identity.model == "dcttech USBRelay4"
        assert identity.port == "usb:001,007"
        assert identity.kind == "relay"
    tx = [e.payload for e in transcript.entries if e.direction == "tx"]
    rx = [e.payload for e in transcript.entries if e.direction == "rx"]
    assert tx[0] == bytes.fromhex("80 06 00 03 00 00 fe 00")
    assert tx[-1] == bytes.fromhex("a0 01 00 03 00 00 08 00")
    assert rx[-1] == b"QAAMZ\x00\x00\x05"
    assert transcript.entries[-1].direction == "event"


@pytest.mark.parametrize(
    ("channel", "on", "payload", "before", "after"),
    [
        (1, True, "ff 01 00 00 00 00 00 00", 0b00, 0b01),
        (2, True, "ff 02 00 00 00 00 00 00", 0b01, 0b11),
        (1, False, "fd 01 00 00 00 00 00 00", 0b11, 0b10),
        (2, False, "fd 02 00 00 00 00 00 00", 0b10, 0b00),
    ],
)
def test_switch_one_relay(channel: int, on: bool, payload: str, before: int, after: int) -> None:
    with expected_transfers(
        [*open_script(state=before), set_report(payload), get_report(after)]
    ) as backend:
        relay = open_hid_relay("QAAMZ", backend=backend)
        relay.set(channel, on)


def test_switch_relay_8_of_an_8_channel_board() -> None:
    with expected_transfers(
        [*open_script("USBRelay8"), set_report("ff 08 00 00 00 00 00 00"), get_report(0x80)]
    ) as backend:
        relay = open_hid_relay(None, backend=backend)
        relay.set(8, True)


def test_all_on_and_all_off() -> None:
    with expected_transfers(
        [
            *open_script("USBRelay4"),
            set_report("fe 00 00 00 00 00 00 00"),
            get_report(0x0F),
            set_report("fc 00 00 00 00 00 00 00"),
            get_report(0x00),
        ]
    ) as backend:
        relay = open_hid_relay(None, backend=backend)
        relay.all_on()
        relay.all_off()


def test_state_reads_the_bitmask_channel_1_first() -> None:
    with expected_transfers([*open_script("USBRelay4"), get_report(0b1010)]) as backend:
        relay = open_hid_relay(None, backend=backend)
        assert relay.state() == (False, True, False, True)


def test_set_serial_writes_fa_and_reads_it_back() -> None:
    with expected_transfers(
        [
            *open_script(),
            set_report("fa 52 49 47 30 31 00 00"),
            get_report(0, serial=b"RIG01"),
        ]
    ) as backend:
        relay = open_hid_relay(None, backend=backend)
        relay.set_serial("RIG01")
        assert relay.serial == "RIG01"
        assert "RIG01" in relay.device


def test_interface_recipient_uses_0x21_and_0xa1() -> None:
    with expected_transfers(
        [
            *open_script(request_type=0xA1),
            set_report("ff 01 00 00 00 00 00 00", request_type=0x21),
            get_report(1, request_type=0xA1),
        ]
    ) as backend:
        relay = open_hid_relay(None, backend=backend, recipient="interface")
        relay.set(1, True)
        assert relay.identify().extra["request_recipient"] == "interface"


def test_close_is_idempotent_and_later_calls_raise() -> None:
    with expected_transfers(open_script()) as backend:
        relay = open_hid_relay(None, backend=backend)
        with relay:
            pass
        relay.close()
        with pytest.raises(Disconnected, match="closed"):
            relay.state()


# ---------------------------------------------------------------------------- wrong replies


def test_relay_that_does_not_follow_raises_state_mismatch() -> None:
    # The mismatching read is confirmed by one more read before the error.
    with expected_transfers(
        [*open_script(), set_report("ff 02 00 00 00 00 00 00"), get_report(0b00), get_report(0b00)]
    ) as backend:
        relay = open_hid_relay(None, backend=backend)
        with pytest.raises(StateMismatch) as caught:
            relay.set(2, True)
    assert caught.value.expected == "01" and caught.value.actual == "00"
    assert "QAAMZ" in str(caught.value)


def test_one_odd_read_is_confirmed_then_accepted() -> None:
    with expected_transfers(
        [*open_script(), set_report("ff 01 00 00 00 00 00 00"), get_report(0b00), get_report(0b01)]
    ) as backend:
        relay = open_hid_relay(None, backend=backend)
        relay.set(1, True)


def test_short_feature_report_raises_protocol_error() -> None:
    script = open_script()
    script[-1] = Transfer(0xA0, 0x01, 0x0300, 0, length=8, reply=b"QAAMZ")
    with (
        expected_transfers(script) as backend,
        pytest.raises(DeviceNotFound, match="short feature report"),
    ):
        open_hid_relay(None, backend=backend)


def test_short_report_after_open_raises_protocol_error() -> None:
    with expected_transfers(
        [*open_script(), Transfer(0xA0, 0x01, 0x0300, 0, length=8, reply=b"QA")]
    ) as backend:
        relay = open_hid_relay(None, backend=backend)
        with pytest.raises(ProtocolError, match="2 bytes, expected 8") as caught:
            relay.state()
    assert caught.value.reply == b"QA"


@pytest.mark.parametrize(
    ("error", "expected_type", "message"),
    [
        (usb_error(errno.ETIMEDOUT, "Operation timed out", timeout=True), DeviceTimeout, "1 s"),
        (usb_error(errno.EPIPE, "Pipe error"), ProtocolError, "STALL"),
        (usb_error(errno.ENODEV, "No such device"), Disconnected, "went away"),
        (usb_error(errno.EBUSY, "Resource busy"), DeviceBusy, "busy"),
        (usb_error(errno.EACCES, "Access denied"), DeviceError, "udev"),
        (usb_error(errno.EIO, "Input/output error"), ProtocolError, "errno 5"),
    ],
)
def test_usb_errors_become_typed_errors(
    error: usb.core.USBError, expected_type: type[DeviceError], message: str
) -> None:
    transcript = ListTranscript()
    failing = Transfer(0x20, 0x09, 0x0300, 0, data=command_report(0xFF, b"\x01"), error=error)
    with expected_transfers([*open_script(), failing]) as backend:
        relay = open_hid_relay(None, backend=backend, transcript=transcript)
        with pytest.raises(expected_type, match=message) as caught:
            relay.set(1, True)
    assert type(caught.value) is expected_type
    assert transcript.entries[-1].direction == "error"
    logged = json.loads(transcript.entries[-1].payload)
    assert logged["setup"] == "2009000300000800"
    assert logged["errno"] == error.errno


# ---------------------------------------------------------------------------- selection


def test_other_vusb_gadget_is_not_a_relay() -> None:
    with (
        expected_transfers(open_script(manufacturer="obdev.at")[:2]) as backend,
        pytest.raises(DeviceNotFound, match=r"manufacturer 'obdev\.at'"),
    ):
        open_hid_relay(None, backend=backend)


def test_unknown_product_string_is_rejected() -> None:
    with (
        expected_transfers(open_script(product="HIDRelay")[:3]) as backend,
        pytest.raises(DeviceNotFound, match="HIDRelay"),
    ):
        open_hid_relay(None, backend=backend)


def test_wrong_serial_names_what_was_found() -> None:
    with (
        expected_transfers(open_script()) as backend,
        pytest.raises(DeviceNotFound, match=r"no board with serial 'XXXXX'; found 'QAAMZ'"),
    ):
        open_hid_relay("XXXXX", backend=backend)


def test_channel_out_of_range_is_refused_before_any_transfer() -> None:
    with expected_transfers(open_script()) as backend:
        relay = open_hid_relay(None, backend=backend)
        with pytest.raises(ValueError, match=r"channels 1\.\.2"):
            relay.set(3, True)
        with pytest.raises(ValueError, match=r"channels 1\.\.2"):
            relay.set(0, True)
        with pytest.raises(TypeError):
            relay.set(True, True)


def test_no_usb_backend_is_reported_cleanly(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_backend(**kwargs: object) -> None:
        raise usb.core.NoBackendError("No backend available")

    monkeypatch.setattr(usb.core, "find", no_backend)
    with pytest.raises(DeviceNotFound, match="no USB backend available"):
        open_hid_relay(None)


# ---------------------------------------------------------------------------- pure helpers


def test_pure_encoders_and_decoders() -> None:
    assert setup_packet(0x21, 0x09, 0x0300, 0, 8) == bytes.fromhex("21 09 00 03 00 00 08 00")
    assert command_report(0xFF, b"\x03") == bytes.fromhex("ff 03 00 00 00 00 00 00")
    with pytest.raises(ValueError, match="longer than 8"):
        command_report(0xFA, b"123456789")
    assert decode_string_descriptor(string_descriptor("USBRelay2")) == "USBRelay2"
    with pytest.raises(ValueError, match="not a string descriptor"):
        decode_string_descriptor(b"\x04\x01\x00\x00")
    assert FeatureReport.decode(b"UNSET\x00\x00\x81").channel_states(8) == (
        True,
        False,
        False,
        False,
        False,
        False,
        False,
        True,
    )
    assert [channel_count_from_product(f"USBRelay{n}") for n in (1, 2, 4, 8)] == [1, 2, 4, 8]
    with pytest.raises(ValueError, match="USBRelay3"):
        channel_count_from_product("USBRelay3")


def test_relay_satisfies_the_protocol() -> None:
    from drivers.base import RelayBoard

    with expected_transfers(open_script()) as backend:
        relay = open_hid_relay(None, backend=backend)
        assert isinstance(relay, RelayBoard)
        assert isinstance(relay, HidUsbRelay)


def test_descriptor_helper_rejects_unknown_fields() -> None:
    with pytest.raises(ValueError, match="idVendr"):
        device_descriptor(1, 2, bus=1, address=1, idVendr=3)
