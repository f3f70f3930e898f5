"""The fingerprint of the scenario a plan was made for, and the check that a plan's
commands are run on that scenario.

A plan's commands are only right for the block, material, friction and ``[plan]``
table (press, target) they were planned on; the mesh and the solver settings may
change (running a plan on a finer mesh is a verification).  ``plan.json`` carries
``scenario_fingerprint = {"sha256": ..., "fields": {...}}`` of :data:`FIELDS`.
"""

from __future__ import annotations

import hashlib
import json

from ..errors import InputError

FIELDS = ("block.size", "material.young", "material.poisson", "friction.mu_x", "friction.mu_y",
          "friction.angle_deg", "plan")
"""Dotted paths into ``Scenario.to_dict()`` that a plan depends on."""


def _get(tables: dict, path: str):
    value = tables
    for part in path.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    return value


def scenario_fingerprint(tables: dict) -> dict:
    """``{"sha256", "fields"}`` of a scenario's tables (``Scenario.to_dict()``)."""
    fields = {path: _get(tables, path) for path in FIELDS}
    text = json.dumps(fields, sort_keys=True, default=str)
    return {"sha256": hashlib.sha256(text.encode()).hexdigest(), "fields": fields}


def check_plan_scenario(plan: dict, tables: dict, path, force: bool = False) -> None:
    """Refuse to run the commands of ``plan`` (a ``plan.json``'s content) on a
    scenario other than the one it was made for, unless ``force``.

    A command file without a fingerprint or a ``scenario`` (a bare ``commands``
    list) is accepted as it is.

    Raises
    ------
    InputError
        Names the fields that differ and their values in the plan and the scenario.
    """
    if force or not isinstance(plan, dict):
        return
    stored = plan.get("scenario_fingerprint")
    if isinstance(stored, dict) and isinstance(stored.get("fields"), dict):
        made_for = stored["fields"]
    elif isinstance(plan.get("scenario"), dict):
        made_for = scenario_fingerprint(plan["scenario"])["fields"]
    else:
        return
    current = scenario_fingerprint(tables)["fields"]
    differ = [k for k in FIELDS if json.dumps(made_for.get(k), sort_keys=True, default=str)
              != json.dumps(current[k], sort_keys=True, default=str)]
    if differ:
        detail = "; ".join(f"{k}: plan {_short(made_for.get(k))}, scenario {_short(current[k])}" for k in differ)
        raise InputError(f"{path} was made for another scenario ({detail}); --force to run it anyway")


def _short(value, limit: int = 60) -> str:
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= limit else text[:limit - 3] + "..."


BLOCK_FIELDS = ("block.size",)
"""What a truth model shares with the planning model in ``closed-loop``: the block's
geometry (the commands move its faces).  Its material, friction, mesh and solver may
differ (a model error is what a closed loop is for); a material that differs is said."""
MATERIAL_FIELDS = ("material.young", "material.poisson", "material.density")


def _differ(a: dict, b: dict, fields) -> list:
    return [k for k in fields if json.dumps(_get(a, k), default=str) != json.dumps(_get(b, k), default=str)]


def check_same_block(model: dict, truth: dict, path, force: bool = False) -> None:
    """Refuse a truth scenario (``Scenario.to_dict()`` of ``path``) of another block size
    than the planning scenario's, unless ``force``; warn when the material differs.

    Raises
    ------
    InputError
        Names the fields that differ and both values.
    """
    import warnings

    from ..errors import InputWarning

    def detail(fields):
        return "; ".join(f"{k}: scenario {_short(_get(model, k))}, truth {_short(_get(truth, k))}" for k in fields)

    differ = _differ(model, truth, BLOCK_FIELDS)
    if differ and not force:
        raise InputError(f"--truth {path} is another block ({detail(differ)}); the closed loop executes the plan on "
                         "the same block (--force to run it anyway)")
    material = _differ(model, truth, MATERIAL_FIELDS)
    if material:
        warnings.warn(f"--truth {path}: the material differs from the model's ({detail(material)}): "
                      "the closed loop runs with this model error", InputWarning, stacklevel=2)
