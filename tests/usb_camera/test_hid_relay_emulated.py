"""The HID USBRelay driver against the emulated boards: lamps, several boards, every fault."""

from __future__ import annotations

import colour
import pytest

from calib.core.spectra import Spectrum
from drivers.base import (
    DeviceBusy,
    DeviceNotFound,
    DeviceTimeout,
    Disconnected,
    ListTranscript,
    ProtocolError,
    StateMismatch,
)
from drivers.relays.hid_usbrelay import find_hid_relays, open_hid_relay
from mocks.lamps import LampBank, SimulatedClock, VirtualLamp, WallClock
from mocks.usb_relay_backend import EmulatedRelayBoard, FakeUsbBackend, UsbFault


def lamp_bank(n_channels: int = 4) -> LampBank:
    led = Spectrum.from_colour(colour.SDS_ILLUMINANTS["LED-B3"])
    fluorescent = Spectrum.from_colour(colour.SDS_ILLUMINANTS["FL2"])
    return LampBank(
        [VirtualLamp("LED-B3", 1, led), VirtualLamp("FL2", 3, fluorescent, kind="fluorescent")],
        n_channels=n_channels,
        clock=SimulatedClock(),
    )


def usbhid_bound(board: EmulatedRelayBoard) -> bool:
    return board.kernel_driver_active


def test_switching_lights_the_lamps() -> None:
    bank = lamp_bank()
    board = EmulatedRelayBoard("LAMPS", 4, lamp_bank=bank)
    with open_hid_relay("LAMPS", backend=FakeUsbBackend([board])) as relay:
        relay.set(3, True)
        assert [lamp.name for lamp, _ in bank.lit()] == ["FL2"]
        relay.all_on()
        assert [lamp.name for lamp, _ in bank.lit()] == ["LED-B3", "FL2"]
        relay.set(1, False)
        assert relay.state() == (False, True, True, True)
        relay.all_off()
        assert bank.lit() == []
    assert board.commands == [
        bytes.fromhex("ff 03 00 00 00 00 00 00"),
        bytes.fromhex("fe 00 00 00 00 00 00 00"),
        bytes.fromhex("fd 01 00 00 00 00 00 00"),
        bytes.fromhex("fc 00 00 00 00 00 00 00"),
    ]


def test_several_boards_are_selected_by_serial() -> None:
    boards = [
        EmulatedRelayBoard("BRD01", 2, address=3),
        EmulatedRelayBoard("BRD02", 8, address=4),
        EmulatedRelayBoard("BRD03", 4, address=5),
        EmulatedRelayBoard("KEYS0", 2, address=6, manufacturer="obdev.at", product="HIDKeys"),
    ]
    backend = FakeUsbBackend(boards)
    found, skipped = find_hid_relays(backend=backend)
    assert [(b.serial, b.channels, b.port) for b in found] == [
        ("BRD01", 2, "usb:001,003"),
        ("BRD02", 8, "usb:001,004"),
        ("BRD03", 4, "usb:001,005"),
    ]
    assert len(skipped) == 1 and "obdev.at" in skipped[0]
    with open_hid_relay("BRD02", backend=backend) as relay:
        relay.set(7, True)
    assert boards[1].relay_states() == (False,) * 6 + (True, False)
    assert boards[0].state_mask == boards[2].state_mask == 0
    with pytest.raises(DeviceNotFound, match="3 boards found") as caught:
        open_hid_relay(None, backend=backend)
    assert "'BRD01'" in str(caught.value) and "'BRD03'" in str(caught.value)


def test_duplicate_serials_are_refused_until_one_is_renamed() -> None:
    first = EmulatedRelayBoard("HW348", 2, address=3)
    second = EmulatedRelayBoard("HW348", 2, address=4)
    backend = FakeUsbBackend([first, second])
    with pytest.raises(DeviceNotFound, match="2 boards share serial 'HW348'"):
        open_hid_relay("HW348", backend=backend)
    backend.unplug(second)
    with open_hid_relay("HW348", backend=backend) as relay:
        relay.set_serial("LAMP2")
    backend.replug(second)
    with open_hid_relay("LAMP2", backend=backend) as relay:
        relay.set(2, True)
    assert first.relay_states() == (False, True)
    assert second.relay_states() == (False, False)


def test_interface_recipient_detaches_usbhid_and_gives_it_back() -> None:
    board = EmulatedRelayBoard("QAAMZ", 2)
    backend = FakeUsbBackend([board])
    transcript = ListTranscript()
    relay = open_hid_relay(None, backend=backend, recipient="interface", transcript=transcript)
    assert not usbhid_bound(board)
    relay.set(1, True)
    relay.close()
    assert usbhid_bound(board)
    assert b"detach_kernel_driver" in b"".join(e.payload for e in transcript.entries)
    # Device-recipient requests work with usbhid bound.
    with open_hid_relay(None, backend=backend) as relay:
        relay.set(2, True)
    assert board.kernel_driver_active is True


def test_transcript_records_every_transfer() -> None:
    transcript = ListTranscript()
    with open_hid_relay(
        None, backend=FakeUsbBackend([EmulatedRelayBoard()]), transcript=transcript
    ) as relay:
        relay.set(1, True)
    directions = [e.direction for e in transcript.entries]
    # LANGID, manufacturer, product, GET_REPORT (tx+rx each), open, SET, GET, close
    assert directions == ["tx", "rx"] * 4 + ["event", "tx", "tx", "rx", "event"]
    assert transcript.entries[9].payload == bytes.fromhex(
        "20 09 00 03 00 00 08 00 ff 01 00 00 00 00 00 00"
    )
    times = [e.monotonic_s for e in transcript.entries]
    assert times == sorted(times)
    assert {e.device for e in transcript.entries[8:]} == {"HID USBRelay QAAMZ on usb:001,004"}


# --------------------------------------------------------------------------------- faults


def test_no_reply_times_out_after_the_transfer_timeout() -> None:
    board = EmulatedRelayBoard()
    clock = SimulatedClock()
    backend = FakeUsbBackend([board], clock=clock)
    relay = open_hid_relay(None, backend=backend, timeout_s=0.25)
    board.inject(UsbFault("timeout", request="set_report"))
    with pytest.raises(DeviceTimeout, match=r"within 0\.25 s") as caught:
        relay.set(1, True)
    assert caught.value.timeout_s == 0.25
    assert clock.now() == pytest.approx(0.25)
    relay.set(1, True)  # one-shot fault: the next command goes through
    assert board.relay_states() == (True, False)


class RecordingWallClock(WallClock):
    """Real time, noting every wait the backend makes on it."""

    def __init__(self) -> None:
        self.waits_s: list[float] = []

    def sleep(self, seconds: float) -> None:
        self.waits_s.append(seconds)
        super().sleep(seconds)


def test_no_reply_in_wall_time_ends_within_its_deadline() -> None:
    board = EmulatedRelayBoard()
    clock = RecordingWallClock()
    relay = open_hid_relay(None, backend=FakeUsbBackend([board], clock=clock), timeout_s=0.05)
    board.inject(UsbFault("timeout", request="get_report"))
    with pytest.raises(DeviceTimeout):
        relay.state()
    # The only time that passed in the driver is one transfer's deadline (what a loaded machine
    # adds to it is not the driver's), not a retry nor libusb's unlimited or default deadline.
    assert clock.waits_s == [pytest.approx(0.05)]


def test_late_reply_within_the_timeout_is_fine_beyond_it_times_out() -> None:
    board = EmulatedRelayBoard()
    clock = SimulatedClock()
    relay = open_hid_relay(None, backend=FakeUsbBackend([board], clock=clock), timeout_s=0.5)
    board.inject(UsbFault("late", request="set_report", delay_s=0.3))
    relay.set(1, True)
    assert clock.now() == pytest.approx(0.3)
    board.inject(UsbFault("late", request="get_report", delay_s=2.0))
    with pytest.raises(DeviceTimeout):
        relay.state()
    assert clock.now() == pytest.approx(0.8)


def test_garbled_report_is_confirmed_by_a_second_read() -> None:
    board = EmulatedRelayBoard("QAAMZ", 2)
    transcript = ListTranscript()
    relay = open_hid_relay(None, backend=FakeUsbBackend([board]), transcript=transcript)
    board.inject(UsbFault("garbled_reply"))
    relay.set(1, True)  # one odd read: the confirmation read is clean
    assert b"state_reread" in transcript.entries[-3].payload
    board.inject(UsbFault("garbled_reply", times=2))
    with pytest.raises(StateMismatch) as caught:
        relay.set(2, True)
    assert caught.value.expected == "11" and caught.value.actual == "00"  # 0b11 inverted


def test_stall_is_a_protocol_error() -> None:
    board = EmulatedRelayBoard()
    relay = open_hid_relay(None, backend=FakeUsbBackend([board]))
    board.inject(UsbFault("stall", request="set_report"))
    with pytest.raises(ProtocolError, match="STALL"):
        relay.all_on()
    assert board.state_mask == 0


def test_disconnect_mid_command_and_replug_at_a_new_address() -> None:
    board = EmulatedRelayBoard("QAAMZ", 2, address=4)
    backend = FakeUsbBackend([board])
    relay = open_hid_relay("QAAMZ", backend=backend)
    relay.set(1, True)
    board.inject(UsbFault("disconnect", request="set_report"))
    with pytest.raises(Disconnected, match="went away"):
        relay.set(2, True)
    with pytest.raises(Disconnected):
        relay.state()
    relay.close()
    with pytest.raises(DeviceNotFound, match="no dcttech USBRelay board found"):
        open_hid_relay("QAAMZ", backend=backend)
    backend.replug(board, address=9)
    with open_hid_relay("QAAMZ", backend=backend) as relay:
        assert relay.identify().port == "usb:001,009"
        assert relay.state() == (False, False)  # relays dropped with the power


def test_busy_device() -> None:
    board = EmulatedRelayBoard()
    relay = open_hid_relay(None, backend=FakeUsbBackend([board]))
    board.inject(UsbFault("busy", request="any"))
    with pytest.raises(DeviceBusy) as caught:
        relay.state()
    assert caught.value.retryable
    assert relay.state() == (False, False)


def test_relay_that_does_not_follow_stops_with_state_mismatch() -> None:
    bank = lamp_bank()
    board = EmulatedRelayBoard("LAMPS", 4, lamp_bank=bank)
    relay = open_hid_relay(None, backend=FakeUsbBackend([board]))
    relay.set(1, True)
    board.inject(UsbFault("stuck_relay", channel=3))
    with pytest.raises(StateMismatch) as caught:
        relay.set(3, True)
    assert caught.value.expected == "1010" and caught.value.actual == "1000"
    assert [lamp.name for lamp, _ in bank.lit()] == ["LED-B3"]
    # The driver now believes the board, not its own wish.
    relay.set(2, True)
    assert relay.state() == (True, True, False, False)


def test_stuck_relay_on_the_third_command_only() -> None:
    board = EmulatedRelayBoard("QAAMZ", 2)
    relay = open_hid_relay(None, backend=FakeUsbBackend([board]))
    fault = board.inject(UsbFault("stuck_relay", skip=2))
    relay.set(1, True)
    relay.set(2, True)
    with pytest.raises(StateMismatch):
        relay.all_off()
    assert fault.fired == 1
    relay.all_off()


def test_truncated_feature_report() -> None:
    board = EmulatedRelayBoard()
    relay = open_hid_relay(None, backend=FakeUsbBackend([board]))
    board.inject(UsbFault("short_reply", short_length=5))
    with pytest.raises(ProtocolError, match="5 bytes, expected 8"):
        relay.set(1, True)


def test_persistent_fault_and_open_failure() -> None:
    board = EmulatedRelayBoard()
    backend = FakeUsbBackend([board])
    board.inject(UsbFault("disconnect", request="open"))
    with pytest.raises(DeviceNotFound, match="no dcttech USBRelay board found"):
        open_hid_relay(None, backend=backend)
    backend.replug(board)
    board.inject(UsbFault("stall", request="string", times=None))
    with pytest.raises(DeviceNotFound, match="cannot read its strings"):
        open_hid_relay(None, backend=backend)


def test_backend_refuses_overlapping_addresses() -> None:
    with pytest.raises(ValueError, match="share a bus address"):
        FakeUsbBackend([EmulatedRelayBoard("A"), EmulatedRelayBoard("B")])
    with pytest.raises(ValueError, match="lamp bank has 4 channels"):
        EmulatedRelayBoard("A", 8, lamp_bank=lamp_bank(4))
