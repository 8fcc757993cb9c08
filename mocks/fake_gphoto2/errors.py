"""``GPhoto2Error`` as python-gphoto2 raises it: ``.code``, ``.string``, ``"[-110] I/O in progress"``."""

from __future__ import annotations

from mocks.fake_gphoto2.constants import ERROR_STRINGS


def gp_result_as_string(code: int) -> str:
    """libgphoto2's text for an error code."""
    return ERROR_STRINGS.get(code, f"Unknown error {code}")


class GPhoto2Error(Exception):
    """A libgphoto2 error: ``code`` (negative int) and ``string`` (its text)."""

    def __init__(self, code: int) -> None:
        self.code = code
        self.string = gp_result_as_string(code)
        super().__init__(f"[{code}] {self.string}")
