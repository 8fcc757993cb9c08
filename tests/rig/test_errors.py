"""One-line summaries of pydantic errors, whatever keys a file sent by anyone holds."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, ValidationError

from rig.errors import first_validation_problem


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")
    timeout_s: float = 1.0


def test_a_key_with_a_line_break_stays_on_one_line() -> None:
    try:
        _Strict.model_validate({"timeout_s": 2.0, "\n": 1, "x\ny": 2})
    except ValidationError as exc:
        problem = first_validation_problem(exc.errors(), "config")
    assert "\n" not in problem
    assert problem == "'\\n': Extra inputs are not permitted"


def test_plain_locations_read_as_dotted_names() -> None:
    errors = [{"loc": ("devices", "camera", 0), "msg": "Input should be\n a number"}]
    assert (
        first_validation_problem(errors, "config") == "devices.camera.0: Input should be a number"
    )
    assert first_validation_problem([{"loc": (), "msg": "bad"}], "record") == "record: bad"
