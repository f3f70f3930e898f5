"""docs/experiment.md: its end-to-end example runs (issue 29), and the pieces it uses.

The example is executed as the page shows it (its ``python`` block), from a temporary
working directory; tests/test_docs.py, once it runs every page, makes this one redundant."""

import math
import re
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def test_the_experiment_page_runs(tmp_path, monkeypatch, capsys):
    text = (ROOT / "docs" / "experiment.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) == 1
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[0], "docs/experiment.md", "exec"), {"__name__": "__doc_example__"})
    out = capsys.readouterr().out
    assert "closed loop error at rest" in out and "'within_tolerance': True" in out
    assert "predicted rest pose" in out


def test_covariance_read_back_from_identified_json():
    from pushplan.identify.document import covariance_from_document

    doc = {"parameters": {"mu_x": {"estimate": 0.3, "sigma": 0.01}, "mu_y": {"estimate": 0.2, "sigma": 0.02},
                          "angle_deg": {"estimate": 5.0, "sigma": None}},
           "correlation": [[1.0, -0.5, None], [-0.5, 1.0, None], [None, None, None]]}
    names, est, C = covariance_from_document(doc)
    assert names == ("mu_x", "mu_y", "angle_deg") and list(est) == [0.3, 0.2, 5.0]
    np.testing.assert_allclose(C[:2, :2], [[1e-4, -1e-4], [-1e-4, 4e-4]])
    assert math.isinf(C[2, 2]) and C[0, 2] == 0.0 and C[2, 1] == 0.0
