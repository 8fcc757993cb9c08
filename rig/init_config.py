"""``rig init``: a commented configuration for the instruments a lab has, or for the digital twin.

The configuration is put together from the templates packaged in ``rig/templates`` (so that
``cd /tmp && rig init --twin && rig demo`` works from an installed package): a header, one block
per device role and kind (``spectrometer-seabreeze.yaml``, ``relays-lcus.yaml``,
``camera-gphoto2.yaml`` …, each commented with what the fields mean and where their values come
from), and the capture policies. Every device is real or ``twin`` on its own; the result is
validated (:func:`rig.config.parse_config`) before it is written, so an impossible mix — a twin
camera behind real relays — is refused with the validator's message. The repository's own
``config.yaml`` is the all-twin rendering (a test keeps them identical).
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from rig.config import ConfigError, RigConfig, parse_config

__all__ = [
    "KINDS",
    "TWIN",
    "packaged_twin_config",
    "render_config",
    "write_new_config",
]

TWIN = "twin"
#: The kinds ``rig init`` writes per role (``twin`` first).
KINDS: dict[str, tuple[str, ...]] = {
    "spectrometer": (TWIN, "pr655", "pr670", "cs2000", "seabreeze", "argyll", "files"),
    "relays": (TWIN, "hid_usbrelay", "lcus", "numato"),
    "camera": (TWIN, "gphoto2"),
}
#: Real kinds ``rig init`` picks for roles not named when it writes for real hardware.
HARDWARE_DEFAULTS = {"spectrometer": "pr655", "relays": "hid_usbrelay", "camera": "gphoto2"}


def _template(name: str) -> str:
    return files("rig").joinpath("templates", name).read_text(encoding="utf-8")


def render_config(spectrometer: str = TWIN, relays: str = TWIN, camera: str = TWIN) -> str:
    """The configuration text for these device kinds (every one ``twin`` by default).

    Raises
    ------
    ValueError
        A kind ``rig init`` has no template for.
    """
    chosen = {"spectrometer": spectrometer, "relays": relays, "camera": camera}
    for role, kind in chosen.items():
        if kind not in KINDS[role]:
            raise ValueError(f"{role}: {kind!r} is not one of {', '.join(KINDS[role])}")
    blocks = [_template(f"{role}-{kind}.yaml") for role, kind in chosen.items()]
    return "".join([_template("header.yaml"), *blocks, "\n", _template("policies.yaml")])


def packaged_twin_config() -> str:
    """The all-twin configuration (what ``rig init --twin`` writes and ``config.yaml`` holds)."""
    return render_config()


def write_new_config(
    path: Path,
    *,
    spectrometer: str = TWIN,
    relays: str = TWIN,
    camera: str = TWIN,
    force: bool = False,
) -> RigConfig:
    """Render, validate and write a configuration to ``path``; return it validated.

    Raises
    ------
    FileExistsError
        ``path`` exists and ``force`` is not set.
    rig.config.ConfigError
        The combination is invalid (the validator's message names the fields).
    """
    text = render_config(spectrometer, relays, camera)
    config = parse_config(text, source=str(path), base_dir=path.resolve().parent)
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; pass --force to replace it")
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text(text, encoding="utf-8")
    temporary.replace(path)
    return config


__all__ += ["ConfigError"]
