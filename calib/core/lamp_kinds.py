"""The kinds of lamp an observation may be (:data:`LAMP_KINDS`), apart from the observations
themselves so that a command line can list them without importing numpy."""

from __future__ import annotations

from typing import Literal

LampKind = Literal["led", "fluorescent", "halogen", "narrowband", "other"]
LAMP_KINDS: tuple[LampKind, ...] = ("led", "fluorescent", "halogen", "narrowband", "other")
