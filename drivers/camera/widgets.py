"""A camera's configuration widgets as a plain table, and the choice of the value to write.

Built from one ``get_config`` tree, the table answers without further library calls: which widget
stands for a logical setting on this body, which choice a requested value maps to, what identifies
the camera, how to trigger bulb. The driver keeps it current from what it reads back.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from drivers.camera.choices import ChoiceKind, match_choice, normalise
from drivers.camera.exposure import ExposureTable, is_bulb_choice, parse_exposure_s

__all__ = [
    "SETTING_WIDGETS",
    "BulbTrigger",
    "WidgetInfo",
    "WidgetTable",
    "same_value",
    "value_text",
]

SETTING_WIDGETS: dict[str, tuple[str, ...]] = {
    "shutterspeed": ("shutterspeed", "shutterspeed2", "exposuretime"),
    "aperture": ("aperture", "f-number", "fnumber"),
    "iso": ("iso", "isospeed", "exposureindex"),
    "whitebalance": ("whitebalance",),
    "imageformat": ("imageformat", "imagequality"),
    "capturetarget": ("capturetarget",),
}
"""Logical setting → widget names to try, in order (libgphoto2 ``camlibs/ptp2/config.c``)."""
CHOICE_KINDS: dict[str, ChoiceKind] = {
    "aperture": "aperture",
    "iso": "iso",
    "imageformat": "imageformat",
    "capturetarget": "capturetarget",
}
IDENTITY_WIDGETS: dict[str, tuple[str, ...]] = {
    "serial": ("serialnumber", "eosserialnumber"),
    "firmware": ("deviceversion", "firmwareversion"),
    "manufacturer": ("manufacturer",),
}
BULB_TOGGLE_WIDGET = "bulb"
"""TOGGLE on Canon EOS, Nikon, Sony, Olympus, Fuji, Panasonic: 1 opens, 0 closes the shutter."""
EOS_RELEASE_WIDGET = "eosremoterelease"
EOS_PRESS_CHOICES = ("Press Full MF", "Press Full", "Press Full AF")
"""Canon remote-release choices that open the shutter, preferred first (MF: no focus hunt → no
busy). Their names changed in libgphoto2 2.5.34, so they are looked up in the widget's choices."""
EOS_RELEASE_CHOICES = ("Release Full",)
CONTAINER_TYPES = ("GP_WIDGET_WINDOW", "GP_WIDGET_SECTION", "GP_WIDGET_BUTTON")
LEAF_TYPES = ("TEXT", "RANGE", "TOGGLE", "RADIO", "MENU", "DATE")


@dataclass
class WidgetInfo:
    """One leaf widget: type (``RADIO`` …), value as text, choices, range ``(min, max, step)``."""

    name: str
    type_name: str
    read_only: bool
    value: str
    choices: tuple[str, ...] = ()
    value_range: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class BulbTrigger:
    """The widget that opens and closes the shutter in bulb, and the values that do it."""

    widget: str
    press: str
    release: str


def value_text(value: object) -> str:
    """A widget value as text (floats keep full precision)."""
    if isinstance(value, float):
        return repr(value)
    return "" if value is None else str(value)


def same_value(read_back: str, written: str) -> bool:
    """Whether a value read back equals the one written (case/space-insensitive, or numerically)."""
    if normalise(read_back) == normalise(written):
        return True
    try:
        return math.isclose(float(read_back), float(written), rel_tol=1e-6, abs_tol=1e-9)
    except ValueError:
        return False


def _toggle_value(value: str) -> str:
    folded = normalise(value)
    if folded in ("1", "on", "true", "yes"):
        return "1"
    if folded in ("0", "off", "false", "no"):
        return "0"
    raise ValueError(f"{value!r} is not on/off (1/0)")


def _range_value(value: str, value_range: tuple[float, float, float]) -> str:
    low, high, step = value_range
    number = float(value)
    if not low - 1e-9 <= number <= high + 1e-9:
        raise ValueError(f"{value} is outside {low:g} … {high:g}")
    if step > 0:
        number = low + round((number - low) / step) * step
    return repr(min(max(number, low), high))


def _exposure_choice(value: str, table: ExposureTable, choices: tuple[str, ...]) -> str:
    exact = [c for c in choices if normalise(c) == normalise(value)]
    if exact:
        return exact[0]
    if is_bulb_choice(value):
        if table.bulb_choice is None:
            raise ValueError(f"no bulb choice among {list(choices)}")
        return table.bulb_choice
    return table.nearest(parse_exposure_s(value))[0]


class WidgetTable:
    """The leaf widgets of one configuration tree, by name."""

    def __init__(self, widgets: dict[str, WidgetInfo]) -> None:
        self.widgets = widgets

    @classmethod
    def from_tree(cls, root: Any, gp: Any) -> WidgetTable:
        """Read every leaf of a ``get_config`` tree (local calls only: the tree is in memory)."""
        skipped = {getattr(gp, name) for name in CONTAINER_TYPES}
        names = {getattr(gp, f"GP_WIDGET_{name}"): name for name in LEAF_TYPES}
        widgets: dict[str, WidgetInfo] = {}
        for widget in _walk(root):
            widget_type = widget.get_type()
            if widget_type in skipped:
                continue
            type_name = names.get(widget_type, str(widget_type))
            try:
                value = widget.get_value()
            except gp.GPhoto2Error:
                value = ""
            info = WidgetInfo(
                name=str(widget.get_name()),
                type_name=type_name,
                read_only=bool(widget.get_readonly()),
                value=value_text(value),
            )
            if type_name in ("RADIO", "MENU"):
                info.choices = tuple(
                    str(widget.get_choice(i)) for i in range(widget.count_choices())
                )
            elif type_name == "RANGE":
                low, high, step = widget.get_range()
                info.value_range = (float(low), float(high), float(step))
            widgets[info.name] = info
        return cls(widgets)

    def __getitem__(self, name: str) -> WidgetInfo:
        return self.widgets[name]

    def find(self, name: str) -> str | None:
        """The widget for a logical setting or a widget name on this camera, or ``None``."""
        for candidate in SETTING_WIDGETS.get(name, ()):
            if candidate in self.widgets:
                return candidate
        return name if name in self.widgets else None

    def missing_message(self, name: str) -> str:
        tried = SETTING_WIDGETS.get(name, (name,))
        writable = sorted(n for n, w in self.widgets.items() if not w.read_only)
        return (
            f"the camera offers no {name!r} setting (widgets tried: {', '.join(tried)}); "
            f"writable widgets: {', '.join(writable)}"
        )

    def is_shutter(self, widget_name: str) -> bool:
        return widget_name == self.find("shutterspeed")

    def choose(self, requested_name: str, widget_name: str, value: str) -> str:
        """The exact value to write for ``value``; ValueError saying what is allowed."""
        widget = self.widgets[widget_name]
        if widget.type_name in ("RADIO", "MENU"):
            if not widget.choices:
                return value
            if self.is_shutter(widget_name):
                return _exposure_choice(value, self.exposure_table(), widget.choices)
            kind = next(
                (
                    CHOICE_KINDS[logical]
                    for logical, names in SETTING_WIDGETS.items()
                    if logical in CHOICE_KINDS and widget_name in names
                ),
                CHOICE_KINDS.get(requested_name, "generic"),
            )
            return match_choice(kind, value, widget.choices)
        if widget.type_name == "TOGGLE":
            return _toggle_value(value)
        if widget.type_name == "RANGE" and widget.value_range is not None:
            return _range_value(value, widget.value_range)
        return value

    def exposure_table(self) -> ExposureTable:
        """The shutter widget's choices as exposures (empty table when there is no shutter)."""
        shutter = self.find("shutterspeed")
        return ExposureTable.from_choices(self.widgets[shutter].choices if shutter else ())

    def identity(self, key: str) -> str | None:
        """``serial``, ``firmware`` or ``manufacturer`` from the status widgets, if present."""
        for name in IDENTITY_WIDGETS[key]:
            widget = self.widgets.get(name)
            if widget is not None and widget.value:
                return widget.value
        return None

    def bulb_trigger(self) -> BulbTrigger | None:
        """How this body opens and closes the shutter in bulb: the ``bulb`` toggle, or Canon's
        remote release; ``None`` when it has neither."""
        toggle = self.widgets.get(BULB_TOGGLE_WIDGET)
        if toggle is not None and toggle.type_name == "TOGGLE" and not toggle.read_only:
            return BulbTrigger(BULB_TOGGLE_WIDGET, "1", "0")
        release = self.widgets.get(EOS_RELEASE_WIDGET)
        if release is not None and not release.read_only:
            press = next((c for c in EOS_PRESS_CHOICES if c in release.choices), None)
            stop = next((c for c in EOS_RELEASE_CHOICES if c in release.choices), None)
            if press is not None and stop is not None:
                return BulbTrigger(EOS_RELEASE_WIDGET, press, stop)
        return None


def _walk(widget: Any) -> Iterator[Any]:
    yield widget
    for i in range(widget.count_children()):
        yield from _walk(widget.get_child(i))
