"""The pieces docs/experiment.md's end-to-end example uses (issue 29); the example
itself, with its own assertion that the closed loop ends within tolerance, is run by
tests/test_docs.py."""

import math
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def test_covariance_read_back_from_identified_json():
    from pushplan.identify.document import covariance_from_document

    doc = {"parameters": {"mu_x": {"estimate": 0.3, "sigma": 0.01}, "mu_y": {"estimate": 0.2, "sigma": 0.02},
                          "angle_deg": {"estimate": 5.0, "sigma": None}},
           "correlation": [[1.0, -0.5, None], [-0.5, 1.0, None], [None, None, None]]}
    names, est, C = covariance_from_document(doc)
    assert names == ("mu_x", "mu_y", "angle_deg") and list(est) == [0.3, 0.2, 5.0]
    np.testing.assert_allclose(C[:2, :2], [[1e-4, -1e-4], [-1e-4, 4e-4]])
    assert math.isinf(C[2, 2]) and C[0, 2] == 0.0 and C[2, 1] == 0.0
