"""The slow fuzz variants together reach the 10⁵ cases issue 6 asks for."""

from __future__ import annotations

import tests.drivers.test_reply_parsers
import tests.rig.test_session_fuzz
from tests.fuzzing import SLOW_BUDGET, SLOW_TOTAL


def test_the_slow_fuzz_variants_add_up_to_the_budget() -> None:
    fuzzed = {tests.drivers.test_reply_parsers.__name__, tests.rig.test_session_fuzz.__name__}
    assert {name.rpartition(".")[0] for name in SLOW_BUDGET} == fuzzed
    assert sum(SLOW_BUDGET.values()) >= SLOW_TOTAL
