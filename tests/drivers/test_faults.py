"""Fault schedules: which command misbehaves, reproducibly, and how replies are damaged."""

from __future__ import annotations

import numpy as np
import pytest

from mocks.faults import Fault, FaultKind, FaultRule, FaultSchedule

NO_REPLY = Fault(FaultKind.NO_REPLY)


def fired(schedule: FaultSchedule, labels: list[str]) -> list[bool]:
    return [schedule.next_fault(label) is not None for label in labels]


def test_nth_fires_only_on_the_nth_matching_command() -> None:
    schedule = FaultSchedule([FaultRule(NO_REPLY, match="M5", nth=3)])
    labels = ["M5", "D13", "M5", "D13", "M5", "M5"]
    assert fired(schedule, labels) == [False, False, False, False, True, False]
    assert [(i.label, i.command_index) for i in schedule.injected] == [("M5", 5)]


def test_match_is_a_regular_expression_anchored_at_the_start() -> None:
    schedule = FaultSchedule([FaultRule(NO_REPLY, match=r"MEDR,1,1,[34]")])
    labels = ["MEDR,1,1,1", "MEDR,1,1,3", "MEDR,1,1,4", "XMEDR,1,1,3", "MEDR,0,0,1"]
    assert fired(schedule, labels) == [False, True, True, False, False]


def test_no_match_means_every_command() -> None:
    schedule = FaultSchedule([FaultRule(NO_REPLY)])
    assert fired(schedule, ["a", "b"]) == [True, True]


def test_probability_is_reproducible_with_the_seed() -> None:
    def run(seed: int) -> list[bool]:
        rule = FaultRule(Fault(FaultKind.ERROR_CODE, code="ER10"), match="MEAS", probability=0.3)
        return fired(FaultSchedule([rule], seed=seed), ["MEAS,1"] * 200)

    first = run(11)
    assert first == run(11)
    assert first != run(12)
    assert 0.2 < np.mean(first) < 0.4


def test_probability_zero_and_one() -> None:
    never = FaultSchedule([FaultRule(NO_REPLY, probability=0.0)])
    always = FaultSchedule([FaultRule(NO_REPLY, probability=1.0)])
    assert fired(never, ["x"] * 20) == [False] * 20
    assert fired(always, ["x"] * 20) == [True] * 20


def test_limit_caps_the_number_of_faults() -> None:
    schedule = FaultSchedule([FaultRule(NO_REPLY, match="status", limit=2)])
    assert fired(schedule, ["status"] * 4) == [True, True, False, False]


def test_the_first_rule_that_fires_wins_and_later_rules_still_count() -> None:
    late = Fault(FaultKind.LATE_REPLY, delay_s=0.5)
    schedule = FaultSchedule([FaultRule(NO_REPLY, match="M5", nth=1), FaultRule(late, nth=2)])
    assert schedule.next_fault("M5") is NO_REPLY
    assert schedule.next_fault("M5") is late  # the second rule saw both commands
    assert schedule.next_fault("M5") is None
    assert schedule.kinds() == {FaultKind.NO_REPLY, FaultKind.LATE_REPLY}


def test_once_builds_a_single_rule_schedule() -> None:
    schedule = FaultSchedule.once(NO_REPLY, "IDDR", nth=2)
    assert fired(schedule, ["IDDR", "IDDR", "IDDR"]) == [False, True, False]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"delay_s": -1.0}, "delay"),
        ({"keep_fraction": 1.0}, "keep_fraction"),
        ({"garbled_bytes": 0}, "garbled_bytes"),
        ({"part": -1}, "part"),
    ],
)
def test_bad_fault_parameters_are_refused(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Fault(FaultKind.NO_REPLY, **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"nth": 0}, "nth"), ({"probability": 1.5}, "probability"), ({"limit": -1}, "limit")],
)
def test_bad_rule_parameters_are_refused(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        FaultRule(NO_REPLY, **kwargs)  # type: ignore[arg-type]


def test_truncation_keeps_the_leading_fraction_and_always_withholds_a_byte() -> None:
    fault = Fault(FaultKind.TRUNCATED_REPLY, keep_fraction=0.5)
    assert fault.kept(b"00000,PR-655\r\n") == b"00000,P"
    assert Fault(FaultKind.TRUNCATED_REPLY, keep_fraction=0.99).kept(b"ab") == b"a"
    assert fault.kept(b"") == b""


def test_garbling_replaces_bytes_with_line_noise_but_keeps_structure() -> None:
    reply = b"CH1: ON \r\nCH2: OFF\r\n"
    fault = Fault(FaultKind.GARBLED_REPLY, garbled_bytes=4)
    garbled = fault.garble(reply, np.random.default_rng(3), keep=b"\r\n")
    changed = [i for i, (a, b) in enumerate(zip(reply, garbled, strict=True)) if a != b]
    assert len(changed) == 4
    assert all(garbled[i] >= 0x80 for i in changed)
    assert garbled.count(b"\r\n") == 2
    again = fault.garble(reply, np.random.default_rng(3), keep=b"\r\n")
    assert again == garbled
    assert fault.garble(b"\r\n", np.random.default_rng(3), keep=b"\r\n") == b"\r\n"
