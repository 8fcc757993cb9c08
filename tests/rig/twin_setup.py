"""A small digital twin for tests: 640×320 frames, a short lens, the shipped lamps and policies.

The shipped configuration renders 1200×800 frames; tests use a 4.8 mm lens on the same 4.8 µm
pixels (1000 px focal length), so the first order from 380 to 780 nm spans 194–424 px and fits a
640 px wide sensor, with a 120 px slit image across a 320 px tall one.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from mocks.bench import TwinSpec
from rig.config import RigConfig
from tests.rig.fakes import fake_config_data

SMALL_CAMERA: dict[str, Any] = {
    "kind": "twin",
    "timeout_s": 5,
    "download_timeout_s": 10,
    "download_s": 0.5,
    "sensor": {"width_px": 640, "height_px": 320},
    "optics": {"focal_length_mm": 4.8, "slit_length_px": 120},
}


def twin_config_data(output_dir: Path | str = "sessions", **camera: Any) -> dict[str, Any]:
    """Configuration data of the small twin; ``camera`` entries update ``devices.camera``."""
    data = fake_config_data(output_dir)
    data["devices"]["camera"] = copy.deepcopy(SMALL_CAMERA) | camera
    # A silent measurement ends in the driver's timeout after 2 s (the twin measures in ms).
    data["devices"]["spectrometer"] = {"kind": "twin", "timeout_s": 5, "measure_timeout_s": 2}
    for lamp in data["lamps"]:
        lamp["warmup"]["tolerance"] = 0.02
    return data


def twin_config(output_dir: Path | str = "sessions", **camera: Any) -> RigConfig:
    """:func:`twin_config_data`, validated."""
    return RigConfig.model_validate(twin_config_data(output_dir, **camera))


def twin_spec(**camera: Any) -> TwinSpec:
    """The :class:`mocks.bench.TwinSpec` of the small twin."""
    return TwinSpec.from_config_data(twin_config(**camera).model_dump(mode="json"))
