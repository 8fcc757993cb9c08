"""Camera bodies across collections (calib.core.camera_bodies) and the rawtoaces-data reader."""

from __future__ import annotations

import doctest
import json
from pathlib import Path

import numpy as np
import pytest

import calib.core.camera_bodies as bodies_module
import calib.core.metrics as metrics_module
from calib.core.camera_bodies import BodyIndex, body_key, read_rawtoaces_aliases
from calib.core.datasets import RAWTOACES_DATA, load_collection
from calib.core.errors import InputError
from calib.core.metrics import channel_relative_errors, relative_error


def test_docstring_examples_hold() -> None:
    assert doctest.testmod(bodies_module).failed == 0
    assert doctest.testmod(metrics_module).failed == 0


@pytest.mark.parametrize(
    "names",
    [
        ("Canon 5D-Mk-II (Jiang-et-al-2013)", "Canon 5DMarkII", "canon eos 5d mark ii"),
        ("Canon 1D-Mk-III", "Canon 1DMarkIII (camspec)"),
        ("Canon 1Ds-Mk-II (Brady-2009)", "Canon EOS-1Ds Mark II"),
        ("Olympus EPL2", "Olympus E-PL2"),
        ("Pentax K5", "Pentax K-5"),
        ("Sony NEX5N", "SONY NEX-5N"),
        ("Nikon D200 (Mauer-2009)", "nikon d200", "Nikon Corporation D200"),
    ],
)
def test_one_body_under_every_collection_s_name(names: tuple[str, ...]) -> None:
    assert len({body_key(name) for name in names}) == 1


def test_different_bodies_stay_apart() -> None:
    keys = {
        body_key(n)
        for n in ("Canon 5D", "Canon 5D Mark II", "Canon EOS-1Ds Mark III", "Canon 1D Mk III")
    }
    assert len(keys) == 4


def test_aliases_join_market_names_and_sensor_siblings(tmp_path: Path) -> None:
    path = tmp_path / "aliases.json"
    path.write_text(
        json.dumps(
            {
                "data": {
                    "camera": {
                        "model": {
                            "Nikon": {
                                "Z 6_2": {
                                    "make": "Nikon",
                                    "model": "Z f",
                                    "comments": "different model, same sensor",
                                },
                                "D7000X": {
                                    "make": "Nikon",
                                    "model": "D7000",
                                    "comments": "same model, alternative name",
                                },
                            }
                        }
                    }
                }
            }
        )
    )
    index = BodyIndex(read_rawtoaces_aliases(path))
    assert index.body("Nikon D7000X") == index.body("nikon d7000")
    assert index.body("Nikon Z 6_2") != index.body("Nikon Z f")
    assert index.sensor("Nikon Z 6_2") == index.sensor("Nikon Z f")
    assert index.body("Canon Rebel T3i") == index.body("Canon 600D (Jiang-et-al-2013)")
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(InputError, match="not a rawtoaces-data alias file"):
        read_rawtoaces_aliases(tmp_path / "bad.json")


def test_channel_relative_errors_average_to_the_relative_error(rng: np.random.Generator) -> None:
    truth = rng.uniform(0.1, 1.0, (31, 3))
    estimate = truth + rng.normal(0, 0.02, truth.shape)
    per_channel = channel_relative_errors(estimate, truth)
    assert per_channel.shape == (3,)
    assert float(np.mean(per_channel)) == pytest.approx(relative_error(estimate, truth), rel=1e-12)


def test_rawtoaces_data_comes_bundled(tmp_path: Path) -> None:
    # A data directory without its own copy reads the one bundled with spectral-rig.
    records = load_collection(RAWTOACES_DATA, tmp_path)
    assert len(records) == 52 and records[0].collection == RAWTOACES_DATA
    index = BodyIndex(read_rawtoaces_aliases())
    assert index.body("Canon Kiss X5") == index.body("Canon EOS 600D")


@pytest.mark.shared_data
def test_rawtoaces_data_is_a_collection(shared_camera_data: Path) -> None:
    records = load_collection(RAWTOACES_DATA, shared_camera_data)
    assert len(records) == 52
    assert all(r.name.endswith("(rawtoaces-data)") for r in records)
    assert all(float(r.sensitivity.values.max()) == pytest.approx(1.0) for r in records)
    aliases = read_rawtoaces_aliases(shared_camera_data / RAWTOACES_DATA / "data" / "aliases.json")
    index = BodyIndex(aliases)
    names = {index.body(r.camera) for r in records}
    assert index.body("Canon Kiss X5") in names  # the EOS 600D
