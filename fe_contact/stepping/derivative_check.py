"""The exact derivatives of :mod:`fe_contact.stepping.derivatives` against
central differences of whole rollouts (as MuJoCo's ``check_derivatives``)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .derivatives import (COMPONENTS, OUTPUTS, _check, input_sizes, parameter_values, rollout_derivatives,
                          with_parameters)
from .step_derivative import report_outputs
from .model import Model, State
from .release import Release
from .sequence import StepSequence

__all__ = ["DerivativeCheck", "check_derivatives"]


@dataclass(frozen=True)
class DerivativeCheck:
    """Exact derivatives against central differences (:func:`check_derivatives`).

    ``analytic``, ``numeric`` (n_steps * 9, n_inputs) as :meth:`RolloutDerivatives.jacobian`;
    ``error`` the entrywise relative error of the normalised Jacobian (NaN where
    the exact derivative does not exist: a contact at a transition); ``inputs``,
    ``outputs`` the column and row names; ``steps`` the central-difference steps.
    """

    analytic: np.ndarray
    numeric: np.ndarray
    error: np.ndarray
    inputs: tuple
    outputs: tuple
    steps: np.ndarray

    @property
    def max_error(self) -> float:
        return float(self.error.max()) if self.error.size else 0.0

    def worst(self) -> str:
        i, j = np.unravel_index(int(np.argmax(self.error)), self.error.shape)
        return (f"{self.outputs[i]} / {self.inputs[j]}: exact {self.analytic[i, j]:.9g}, "
                f"central difference {self.numeric[i, j]:.9g} (error {self.error[i, j]:.2g})")


def check_derivatives(model: Model, commands, state: State | None = None, parameters=None,
                      rel_step: float = 1e-5, floor: float = 1e-4, release: Release | None = None) -> DerivativeCheck:
    """Compare :func:`~fe_contact.stepping.derivatives.rollout_derivatives` with
    central differences of rollouts (as MuJoCo's ``check_derivatives``).

    Input ``j`` is stepped by ``h_j = rel_step * s_j``, ``s_j`` its typical
    size (:func:`~fe_contact.stepping.derivatives.input_sizes`: the largest
    command translation or rotation, ``|value|`` of a parameter, 1 rad for the
    angle).  The Jacobian is normalised, ``J_ij s_j / o_i`` (``o_i`` the largest
    value of output kind ``i`` over the rollout: lengths, angles, forces), and
    the error of an entry is ``|exact - central| / max(|central|, floor * max
    |central|)``: entries far below the dominant sensitivity are compared at
    ``floor`` of it.  (Lengths are scaled by at least the largest command
    translation, angles by at least that over the block's size.)  The step
    trades the central differences' own ``h^2`` error against the solvers'
    noise divided by ``h``: 1e-5 suits soft blocks at tight tolerances, a steel
    block wants 1e-4.  The central differences' rollouts run without
    Anderson's mixing (``SolverOptions.acceleration`` 0): its discrete choices
    (mix, plain, reject) make a converged state's error a non-smooth function
    of the input at the tolerance's level, which the differences divide by
    ``h`` (docs/derivatives.md).  For the same reason a release's load steps are
    solved to ``newton_tol`` here, in the exact rollout and the differences alike
    (``SolverOptions.path_tol`` set to it): through a path solved to ``path_tol``
    the differences would divide its noise by ``h`` (errors of 1e-3 to 5e-2 measured).

    Raises
    ------
    ValueError
        As :func:`~fe_contact.stepping.derivatives.rollout_derivatives`, or a rollout that does not converge.
    """
    commands, parameters = _check(model, commands, parameters, release)
    if release is not None and model.options.path_tol > model.options.newton_tol:
        model = replace(model, options=replace(model.options, path_tol=model.options.newton_tol))
    exact = rollout_derivatives(model, commands, state, parameters, release=release)
    if not exact.converged:
        raise ValueError(f"the rollout does not converge: {exact.message}")
    typical = input_sizes(model, commands, parameters)
    steps = rel_step * typical
    numeric = _central_differences(model, commands, state, parameters, release, steps)
    error, names_out = _normalised_error(model, commands, exact, numeric, typical, floor)
    names_in = tuple(f"{c}[{k}]" for k in range(len(commands)) for c in COMPONENTS) + tuple(parameters)
    return DerivativeCheck(exact.jacobian(), numeric, error, names_in, names_out, steps)


def _central_differences(model, commands, state, parameters, release, steps) -> np.ndarray:
    """Central differences (n_rows * 9, n_inputs) of the outputs of plain
    rollouts without Anderson's mixing, input ``j`` stepped by ``steps[j]``."""
    smooth = model if model.options.acceleration == 0 else replace(
        model, options=replace(model.options, acceleration=0))
    values = parameter_values(model)

    def outputs(j, h):
        cmds, mdl = list(commands), smooth
        if j < 4 * len(commands):
            k, c = divmod(j, 4)
            cmds[k] = replace(cmds[k], **{COMPONENTS[c]: getattr(cmds[k], COMPONENTS[c]) + h})
        else:
            p = parameters[j - 4 * len(commands)]
            mdl = with_parameters(smooth, **{p: values[p] + h})
        return _plain(mdl, cmds, state, release)

    return np.column_stack([(outputs(j, h) - outputs(j, -h)).ravel() / (2 * h) for j, h in enumerate(steps)])


def _normalised_error(model, commands, exact, numeric, typical, floor) -> tuple[np.ndarray, tuple]:
    """The entrywise relative error of the normalised Jacobians (:func:`check_derivatives`) and the row names."""
    arr = np.array([[c.dx, c.dy, c.dz, c.dtheta] for c in commands])
    size = max(model.mesh.size)
    move = max(float(np.abs(arr[:, :3]).max()), size * 1e-4)
    o = np.abs(exact.outputs)
    kind = np.array([0, 0, 1, 2, 2, 2, 0, 0, 1])
    scale = np.maximum([o[:, kind == g].max() for g in range(3)], [move, move / size, 1e-300])[kind]
    norm = np.tile(scale, exact.outputs.shape[0])[:, None]
    A, N = exact.jacobian() * typical / norm, numeric * typical / norm
    err = np.abs(A - N) / np.maximum(np.abs(N), floor * np.abs(N).max())
    names_out = tuple(f"{o}[{k if k < len(commands) else 'rest'}]" for k in range(exact.outputs.shape[0])
                      for o in OUTPUTS)
    return err, names_out


def _plain(model, commands, state, release=None) -> np.ndarray:
    """Outputs (n_steps, 9) of a plain rollout, and with ``release`` one more
    row: the rest; ValueError if a step fails."""
    start = None if state is None else replace(state, tangent=None)
    out = []
    for k, (state, report) in enumerate(StepSequence(model, commands, start, release=release)):
        if not report.converged:
            raise ValueError(f"central difference: step {k + 1} did not converge: {report.message}")
        if k < len(commands) or release is None:
            out.append(report_outputs(report, state))
    if release is not None:
        out.append(report_outputs(report, state))
    return np.array(out)
