"""The three friction cases of sect. 9 of Feng, Hjiaj, de Saxce, Mroz (2006) and
what is measured on each step: the scenarios (shipped ``paper_case1..3.toml`` with
mesh / quadrature / local-solver overrides), the push direction, the lower-face
fields and the per-step record of ``report.json``."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fe_contact import Model, NodeStatus, StepReport

from ..config.scenario import MAX_ELEMENTS, Scenario, load_scenario
from ..errors import InputError
from ..resources import scenario_path
from ..run import StepSummary

CASES = ("paper_case1", "paper_case2", "paper_case3")
"""Isotropic (mu_x = mu_y = 0.3), anisotropic, strongly anisotropic (mu_y = 0.05)."""


def case_scenarios(elements=None, quadrature=None, local_method=None) -> list[Scenario]:
    """The three paper scenarios, with optional mesh / quadrature / local-solver overrides.

    Raises
    ------
    InputError
        ``elements`` is not three integers >= 1 (at most :data:`MAX_ELEMENTS` hex8),
        ``quadrature`` not 2 or 3.
    """
    changes = {}
    if elements is not None:
        elements = tuple(elements)
        if len(elements) != 3 or any(isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in elements):
            raise InputError(f"elements must be three integers >= 1, got {elements!r}")
        if math.prod(elements) > MAX_ELEMENTS:
            raise InputError(f"elements must give at most {MAX_ELEMENTS} hex8, got {elements!r}")
        changes["elements"] = elements
    if quadrature is not None:
        if quadrature not in (2, 3):
            raise InputError(f"quadrature must be 2 or 3, got {quadrature!r}")
        changes["quadrature"] = quadrature
    out = []
    for name in CASES:
        sc = load_scenario(scenario_path(f"{name}.toml"))
        solver = {} if local_method is None else {"solver": dataclasses.replace(sc.solver, local_method=local_method)}
        out.append(dataclasses.replace(sc, **changes, **solver))
    return out


def push_direction(scenario: Scenario) -> np.ndarray:
    """(2,) unit vector of the total in-plane upper-face motion after the first step."""
    d = np.array([[c.dx, c.dy] for c in scenario.commands[1:]]).sum(axis=0)
    norm = float(np.hypot(*d))
    if norm == 0.0:
        raise InputError(f"scenario {scenario.name} has no in-plane push after its first step")
    return d / norm


def direction_deg(v) -> float:
    """Angle of the 2D vector ``v`` from x, degrees in (-180, 180]."""
    return math.degrees(math.atan2(v[1], v[0]))


def lower_grid(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Reference x and y (m) of the lower-face nodes on their grid, shape (ny+1, nx+1) each."""
    nx, ny, _ = model.mesh.divisions
    X = model.mesh.nodes[model.mesh.lower]
    return X[:, 0].reshape(ny + 1, nx + 1), X[:, 1].reshape(ny + 1, nx + 1)


def node_field(report: StepReport, name: str) -> np.ndarray:
    """(n_lower,) nodal field ``slip`` (m), ``r_n`` (N) or ``pressure`` (Pa)."""
    if name == "slip":
        return report.slip
    if name == "r_n":
        return report.reaction_local[:, 0]
    if name == "pressure":
        return report.pressure
    raise InputError(f"unknown field {name!r} (slip, r_n, pressure)")


def extreme(model: Model, values: np.ndarray, mask: np.ndarray, fn) -> tuple[float, list[float]]:
    """``fn`` (``np.argmax`` / ``np.argmin``) of the lower-face ``values`` over ``mask``:
    the value and the reference (x, y) of its node, m."""
    idx = np.flatnonzero(mask)
    k = idx[fn(values[idx])]
    return float(values[k]), model.mesh.nodes[model.mesh.lower[k], :2].tolist()


@dataclasses.dataclass(frozen=True)
class StepRecord:
    """A step of ``report.json``: its :class:`~pushplan.run.StepSummary` plus where
    the extremes sit (reference x, y in m; pressure over nodes in contact, None when
    none is), the ``r_n`` extremes (N) and the centroid motion directions (deg; None
    before the upper face moved in-plane)."""

    summary: StepSummary
    max_slip_at: list[float]
    r_n_max: float
    r_n_max_at: list[float]
    r_n_min: float
    r_n_min_at: list[float]
    pressure_max_at: list[float] | None
    pressure_min_at: list[float] | None
    push_direction_deg: float
    upper_direction_deg: float | None
    lower_direction_deg: float | None

    def to_dict(self) -> dict:
        """The ``report.json`` row: the ``summary.json`` step keys, then the fields above."""
        extra = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)[1:]}
        return {**self.summary.to_dict(), **extra}


def step_record(model: Model, report: StepReport, push: np.ndarray) -> StepRecord:
    """The :class:`StepRecord` of a converged step; ``push`` the (2,) push direction."""
    contact = report.node_status != NodeStatus.SEPARATED
    every = np.ones_like(contact)
    rn = report.reaction_local[:, 0]
    r_n_max, r_n_max_at = extreme(model, rn, every, np.argmax)
    r_n_min, r_n_min_at = extreme(model, rn, every, np.argmin)
    p_max_at = p_min_at = None
    if contact.any():
        p_max_at = extreme(model, report.pressure, contact, np.argmax)[1]
        p_min_at = extreme(model, report.pressure, contact, np.argmin)[1]
    up, lo = report.upper_centroid[:2], report.lower_centroid[:2]
    moved = np.hypot(*up) > 0
    return StepRecord(
        summary=StepSummary.from_report(report), max_slip_at=extreme(model, report.slip, every, np.argmax)[1],
        r_n_max=r_n_max, r_n_max_at=r_n_max_at, r_n_min=r_n_min, r_n_min_at=r_n_min_at,
        pressure_max_at=p_max_at, pressure_min_at=p_min_at, push_direction_deg=direction_deg(push),
        upper_direction_deg=direction_deg(up) if moved else None,
        lower_direction_deg=direction_deg(lo) if moved else None,
    )
