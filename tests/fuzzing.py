"""Fuzz tests in two sizes: a few hundred examples in the default suite, many more when slow.

:func:`fuzz` turns one test body into two hypothesis tests over the same strategies: ``test_x``
with :data:`FAST_EXAMPLES` examples and ``test_x_slow`` (marked ``slow``, run by ``make test-all``)
with as many as the body asks for. The slow variants of the reader and parser fuzz tests add up to
more than 10⁵ cases (:data:`SLOW_TOTAL` is checked by ``tests/test_fuzz_budget.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis.strategies import SearchStrategy

FAST_EXAMPLES = 200
"""Examples per fuzz test in the default suite."""
SLOW_TOTAL = 100_000
"""What the slow variants must reach together."""

SLOW_BUDGET: dict[str, int] = {}
"""Examples of every slow variant, by test name (filled at import)."""

_COMMON = settings(
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    database=None,
)


def fuzz(
    slow_examples: int, **strategies: SearchStrategy[Any]
) -> Callable[[Callable[..., None]], tuple[Callable[..., None], Callable[..., None]]]:
    """``test_x, test_x_slow = fuzz(10_000, reply=replies)(body)``."""

    def variants(body: Callable[..., None]) -> tuple[Callable[..., None], Callable[..., None]]:
        # The default suite draws the same examples every run (CI must not be flaky); the slow
        # variant explores afresh each time.
        fast = settings(_COMMON, max_examples=FAST_EXAMPLES, derandomize=True)(
            given(**strategies)(body)
        )
        slow = settings(_COMMON, max_examples=slow_examples)(given(**strategies)(body))
        SLOW_BUDGET[f"{body.__module__}.{body.__name__}"] = slow_examples
        return fast, pytest.mark.slow(slow)

    return variants
