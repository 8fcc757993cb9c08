import numpy as np
import pytest

from calib.core.errors import InputError
from calib.core.metrics import angular_error_deg, mapping_relative_error, relative_error


def test_relative_error_ignores_overall_scale_and_matches_definition():
    truth = np.array([[1.0, 0.5, 0.2], [0.5, 1.0, 0.4], [0.1, 0.2, 0.8]])
    assert relative_error(3 * truth, truth) == pytest.approx(0.0, abs=1e-15)
    estimate = truth.copy()
    estimate[0, 0] += 0.3
    expected = (np.sqrt(0.3**2 / 3) / 1.0) / 3
    assert relative_error(estimate, truth, normalise=False) == pytest.approx(expected)


def test_relative_error_rejects_bad_shapes():
    with pytest.raises(InputError):
        relative_error(np.ones((3, 2)), np.ones((3, 2)))


def test_mapping_relative_error_is_rms_over_span():
    truth = np.linspace(400, 700, 11)
    assert mapping_relative_error(truth + 3.0, truth) == pytest.approx(0.01)


def test_angular_error():
    assert angular_error_deg([1, 0, 0], [0, 1, 0]) == pytest.approx(90.0)
    assert angular_error_deg([1, 1, 1], [2, 2, 2]) == pytest.approx(0.0, abs=1e-6)
