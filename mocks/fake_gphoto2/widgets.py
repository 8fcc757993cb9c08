"""``CameraWidget``: the configuration tree python-gphoto2 hands out.

A widget tree is a snapshot: ``get_config`` builds a new one from the body's current values, and
changing a widget changes nothing on the camera until it is passed to ``set_config`` /
``set_single_config``, as with libgphoto2.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from mocks.fake_gphoto2.constants import (
    GP_ERROR_BAD_PARAMETERS,
    GP_WIDGET_DATE,
    GP_WIDGET_MENU,
    GP_WIDGET_RADIO,
    GP_WIDGET_RANGE,
    GP_WIDGET_SECTION,
    GP_WIDGET_TEXT,
    GP_WIDGET_TOGGLE,
    GP_WIDGET_WINDOW,
)
from mocks.fake_gphoto2.errors import GPhoto2Error

WidgetValue = str | int | float


@dataclass(frozen=True)
class WidgetSpec:
    """A widget a fake body offers.

    Parameters
    ----------
    name, label
        Widget name (``shutterspeed``) and label (``Shutter Speed``).
    widget_type
        One of the ``GP_WIDGET_*`` leaf types.
    section
        Parent section name (``capturesettings``, ``imgsettings``, ``settings``, ``status``,
        ``actions``).
    value
        Value at power-on.
    choices
        For RADIO / MENU widgets.
    read_only
        Whether the camera refuses writes.
    value_range
        ``(min, max, step)`` for RANGE widgets.
    """

    name: str
    label: str
    widget_type: int
    section: str
    value: WidgetValue
    choices: tuple[str, ...] = ()
    read_only: bool = False
    value_range: tuple[float, float, float] = (0.0, 0.0, 0.0)


class CameraWidget:
    """One node of a configuration tree (python-gphoto2's ``CameraWidget`` call surface)."""

    def __init__(
        self,
        widget_type: int,
        name: str,
        label: str = "",
        *,
        value: WidgetValue | None = None,
        choices: Sequence[str] = (),
        read_only: bool = False,
        value_range: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self._type = widget_type
        self._name = name
        self._label = label or name
        self._value = value
        self._choices = list(choices)
        self._read_only = read_only
        self._range = value_range
        self._children: list[CameraWidget] = []
        self._parent: CameraWidget | None = None
        self._changed = False

    @classmethod
    def from_spec(cls, spec: WidgetSpec, value: WidgetValue) -> CameraWidget:
        return cls(
            spec.widget_type,
            spec.name,
            spec.label,
            value=value,
            choices=spec.choices,
            read_only=spec.read_only,
            value_range=spec.value_range,
        )

    def append(self, child: CameraWidget) -> None:
        child._parent = self
        self._children.append(child)

    # ----------------------------------------------------------------- identity

    def get_name(self) -> str:
        return self._name

    def get_label(self) -> str:
        return self._label

    def get_type(self) -> int:
        return self._type

    def get_readonly(self) -> int:
        return int(self._read_only)

    def get_parent(self) -> CameraWidget | None:
        return self._parent

    def get_root(self) -> CameraWidget:
        node = self
        while node._parent is not None:
            node = node._parent
        return node

    # ----------------------------------------------------------------- value

    def get_value(self) -> WidgetValue:
        if self._type in (GP_WIDGET_WINDOW, GP_WIDGET_SECTION) or self._value is None:
            raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
        return self._value

    def set_value(self, value: WidgetValue) -> None:
        """Type-checked like the bindings: str for text/choices, int for toggle/date, float range."""
        if self._type in (GP_WIDGET_TEXT, GP_WIDGET_RADIO, GP_WIDGET_MENU):
            if not isinstance(value, str):
                raise TypeError(f"in method 'set_value', expected str, got {type(value).__name__}")
        elif self._type in (GP_WIDGET_TOGGLE, GP_WIDGET_DATE):
            if isinstance(value, bool) or not isinstance(value, int):
                raise TypeError(f"in method 'set_value', expected int, got {type(value).__name__}")
        elif self._type == GP_WIDGET_RANGE:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise TypeError(
                    f"in method 'set_value', expected float, got {type(value).__name__}"
                )
            value = float(value)
        else:
            raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
        self._value = value
        self._changed = True

    def changed(self) -> int:
        return int(self._changed)

    def set_changed(self, changed: int) -> None:
        self._changed = bool(changed)

    def get_range(self) -> tuple[float, float, float]:
        if self._type != GP_WIDGET_RANGE:
            raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
        return self._range

    # ----------------------------------------------------------------- choices

    def count_choices(self) -> int:
        return len(self._choices)

    def get_choice(self, index: int) -> str:
        if not 0 <= index < len(self._choices):
            raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
        return self._choices[index]

    def get_choices(self) -> Iterator[str]:
        return iter(list(self._choices))

    # ----------------------------------------------------------------- children

    def count_children(self) -> int:
        return len(self._children)

    def get_child(self, index: int) -> CameraWidget:
        if not 0 <= index < len(self._children):
            raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)
        return self._children[index]

    def get_children(self) -> tuple[CameraWidget, ...]:
        return tuple(self._children)

    def get_child_by_name(self, name: str) -> CameraWidget:
        """Depth-first search by name; ``GPhoto2Error(-2)`` when absent, as libgphoto2 does."""
        for node in self._walk():
            if node is not self and node._name == name:
                return node
        raise GPhoto2Error(GP_ERROR_BAD_PARAMETERS)

    def _walk(self) -> Iterator[CameraWidget]:
        yield self
        for child in self._children:
            yield from child._walk()

    def leaves(self) -> Iterator[CameraWidget]:
        """Every non-container widget below (fake-only helper)."""
        for node in self._walk():
            if node._type not in (GP_WIDGET_WINDOW, GP_WIDGET_SECTION):
                yield node
