"""The release in a rollout's derivatives (:mod:`fe_contact.stepping.derivatives`):
the steps a release took (a failed step's halves), the heights it chose as
functions of its path, and the put-down's and the load steps' roots.

The release is differentiated as the discrete map the schedule took
(:class:`~fe_contact.stepping.release.ReleaseSchedule`, read back from the
run: a change of the schedule carries over).  A bonded lift's steps are held
steps at heights the schedule chose after each report; each height is
differentiated as the schedule computed it (a lift step ``h + d / n``, ``d``
the press depth; a put-down target of
:func:`~fe_contact.stepping.release_path.put_down_target`, a function of the
heights and forces met, of the weight and of ``E A / H``), and the last one,
the put-down's root ``h*`` where the plate carries nothing, by the implicit
function theorem on ``g(h*, p) = F_z = 0``: ``dh*/dp = -g_p / g_h``, ``g_h``
from one more input column (the step's own height).  The path matters: the
put-down overshoots below ``h*`` and comes back, and the contacts that slip
on the way keep it.  A frictional pad's load step finds its height as the
root of its load (:func:`load_step_root`), differentiated the same way.

A pad's load step as it was taken (:func:`load_step_derivative`): its backward-Euler
map ``S' = BE(S, P)`` (``S`` the displacements, contact forces, the pad's pose and
the plate's) by the step's sensitivity with its own height as one more input, that
height then eliminated as the root of the load.  The implicit midpoint rule
(:mod:`~fe_contact.stepping.midpoint`, the default
``Release.scheme``) from ``S_a`` (pad load ``P_a``) to ``P_b``,

    P_m = (P_a + P_b) / 2,    S_m = BE(S_a, P_m),    S_b = 2 S_m - S_a,

differentiates as

    dP_m = (dP_a + dP_b) / 2,   dS_m = dBE(dS_a; P_m, dP_m),   dS_b = 2 dS_m - dS_a,

``dP_a = -dF_z,a`` the start's own pad load (the previous step's output: a function of
the path), ``dP_b`` the schedule's (:func:`~fe_contact.stepping.release.pad_load_schedule`).
The outputs at ``S_b``: the lower face's pose of ``U_b``, the pad's force ``2 F_m -
F_a`` (linear in the contact forces), the plate's pose ``2 p_m - p_a``.  Where the
half step may be extrapolated only by ``w < 1``
(:func:`~fe_contact.stepping.midpoint.extrapolation_fraction`: a contact would leave its
branch of the contact law; 0 at a jump of the load or an inverted element) and a
backward-Euler step from ``S_w = S_m + w (S_m - S_a)`` ends the step,

    dS_w = (1 + w) dS_m - w dS_a + (S_m - S_a) dw,    S_b = BE(S_w, P_b),

``dw`` the derivative of the contact's bound that sets ``w`` (:func:`_fraction_derivative`,
which reads the contact forces' derivatives that
:class:`~fe_contact.stepping.step_derivative.StateDerivative` carries): two
sensitivities, each with its own height's root.  The branch margins checked
(:mod:`~fe_contact.stepping.transitions`) are those of the contacts at each
backward-Euler solve's end (``S_m``, and ``S_b`` where ``w < 1``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .midpoint import contact_gaps, extrapolation_fraction, fraction_bounds, missed_load
from .model import Model, State, Status, StepReport
from .pad_load import pad_normal_load
from .sensitivity import lower_pose_derivative
from .sequence import StepSequence
from .step import half_command, step
from .step_derivative import report_outputs, step_derivative

__all__ = ["LoadStep", "RecordingSequence", "load_step_derivative", "load_step_root", "put_down_root",
           "release_height_derivative", "whole_steps"]


class RecordingSequence(StepSequence):
    """:class:`~fe_contact.stepping.sequence.StepSequence` that keeps the steps it
    takes since the last one it yielded (the parts a step was taken in, a midpoint
    load step's backward-Euler solves among them), and a step's derivative follows
    the parts that were kept."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.taken = []

    def _step(self, model, state, command, consume=False, guess=None):
        out = super()._step(model, state, command, consume=consume, guess=guess)
        self.taken.append((state, *out))
        return out

    def parts(self, end: State) -> list:
        """The converged steps from the last yielded state that end in ``end``
        (equal displacements: a part's end is copied into the next part's
        start), in order: ``[(start, state, report), ...]``; None if there is no
        such chain."""
        taken, self.taken = self.taken, []
        by_start = {}
        for start, state, report in taken:
            if report.converged:
                by_start.setdefault(start.displacement.tobytes(), []).append((start, state, report))
        goal = end.displacement.tobytes()

        def walk(key):
            for part in by_start.get(key, []):
                after = part[1].displacement.tobytes()
                if after == goal:
                    return [part]
                rest = walk(after)
                if rest:
                    return [part, *rest]
            return None

        return walk(taken[0][0].displacement.tobytes()) if taken else []


def release_height_derivative(model: Model, schedule, d_current: np.ndarray, path: list, d_young: np.ndarray,
                              d_density: np.ndarray) -> np.ndarray:
    """Derivative (J,) of the height the release's last command goes to.

    The schedule says how it chose that height
    (``ReleaseSchedule.height_partials``): a lift step ``h + d / steps``
    (``d`` the press depth), an absolute height, a put-down's target
    (:func:`~fe_contact.stepping.release_path.put_down_target`, a function of
    the put-down's points, plate height and vertical force, of the weight ``W
    = rho g V`` and of the column's stiffness ``k = E A / H``); a pad's load
    step's height is a root instead (:func:`load_step_root`).  ``path`` holds ``(d_h, d_F_z)`` of the release's start
    (the loaded step) and of each release step so far.  ``d_young``, ``d_density``
    (J,) are the inputs' derivatives of ``E``, ``rho``.  A put-down's last
    height is then replaced by the root (:func:`put_down_root`).
    """
    out = np.zeros(d_current.shape)
    points = schedule.contact_points
    entries = path[1:]
    first = len(entries) - len(points)  # the points are the last steps' (the current one excepted)
    for key, c in schedule.height_partials.items():
        if key == "current":
            out += c * d_current
        elif key == "depth":  # d = -t_z at the release's start
            out -= c * path[0][0]
        elif key == "weight":
            out += c * model.weight / model.material.density * d_density
        elif key == "stiffness":
            out += c * schedule.axial_stiffness / model.material.young * d_young
        else:
            kind, i = key
            h, force = entries[first + i]
            out += c * (h if kind == "h" else force)
    return out


def put_down_root(schedule, d_rest: np.ndarray, force_z: int, d_state: tuple) -> tuple:
    """The root condition of a put-down (:meth:`~fe_contact.stepping.release.ReleaseSchedule._put_down`):
    the last height ``h*`` is where the plate's vertical force vanishes,
    ``g(h*, p) = F_z = 0``, so ``dh*/dp = -g_p / g_h`` (implicit function
    theorem; ``g_h`` the last column, the last step's own height) and every
    derivative gains ``d/dh dh*/dp``.  ``d_rest`` (9, J), the rest's output
    derivatives (row ``force_z`` the plate's vertical force), is corrected in
    place; returns the state's derivatives ``d_state`` (arrays (., J))
    corrected.  Nothing to do when the block was not put down (no weight, or
    a frictional pad: it ends where the release left it)."""
    if schedule.pad or not (schedule.lifted_off and schedule.contact_points):
        return d_state
    g = d_rest[force_z]
    dh = -g / g[-1]
    dh[-1] = 0.0
    d_rest += np.outer(d_rest[:, -1], dh)
    return tuple(x + np.outer(x[:, -1], dh) for x in d_state)


def load_step_root(d_out: np.ndarray, force_z: int, load: float, d_load: np.ndarray, d_state: tuple) -> tuple:
    """A pad's load step (:mod:`fe_contact.stepping.pad_load`) found its height
    ``h`` where the pad's vertical force is ``F_z(h, p) = -P(p)`` (``P`` the
    step's load, of the loaded load and the weight,
    :func:`~fe_contact.stepping.release.pad_load_schedule`; ``d_load`` its
    derivative (J,)): ``dh/dp = -(dF_z/dp + dP/dp) / (dF_z/dh)`` (implicit
    function theorem, ``dF_z/dh`` the last column, the step's own height),
    added to every derivative through its last column.  ``d_out`` (9, J) the
    step's output derivatives (row ``force_z`` the pad's vertical force),
    ``d_state`` the state's (arrays (., J)); returns both corrected.  At ``P =
    0`` the pad is open and the block's state does not depend on ``h``."""
    if load == 0:
        return d_out, d_state
    g = d_out[force_z] + d_load
    dh = -g / g[-1]
    dh[-1] = 0.0
    return d_out + np.outer(d_out[:, -1], dh), tuple(x + np.outer(x[:, -1], dh) for x in d_state)

def whole_steps(model, parts):
    """``parts`` (start, state, report) with every step that a frictional pad
    took in halves (:func:`~fe_contact.stepping.step.step`, its whole command
    having failed) replaced by its halves, taken again (the same steps), or
    None if one does not converge."""
    out = []
    for start, end, report in parts or []:
        if "half steps" not in report.message:
            out.append((start, end, report))
            continue
        half = half_command(report.command)
        middle, first = step(model, start, half)
        finish, second = step(model, middle, half)
        if not (first.converged and second.converged):
            return None
        out += whole_steps(model, [(start, middle, first), (middle, finish, second)]) or [None]
    return None if None in out else out


@dataclass(frozen=True)
class LoadStep:
    """A pad's load step to differentiate along J inputs (the last the step's own height).

    Attributes
    ----------
    load : float
        The schedule's load at the step's end ``P_b``, N.
    d_load : ndarray, shape (J,)
        Its derivative.
    d_start_out : ndarray, shape (9, J)
        The outputs' derivatives at the step's start (the previous step's;
        :data:`~fe_contact.stepping.derivatives.OUTPUTS`).
    midpoint : bool
        Taken by the implicit midpoint rule.
    force_z : int
        The row of the pad's vertical force in the outputs.
    seeds : ndarray, shape (8, J)
        The parameters' derivatives along the inputs
        (:func:`~fe_contact.stepping.step_derivative.step_derivative`).
    """

    load: float
    d_load: np.ndarray
    d_start_out: np.ndarray
    midpoint: bool
    force_z: int
    seeds: np.ndarray


def load_step_derivative(model, taken: list, chain: list | None, state: State, new_state: State, report: StepReport,
                         step: LoadStep, d_state):
    """The derivatives of a load step from ``state`` that ended in ``(new_state,
    report)`` (module docstring: backward Euler, or the midpoint rule).  ``taken``
    are the backward-Euler steps the step solved, in order, as ``(start, end,
    report)``; ``chain`` those of them that lead to ``new_state`` (None if none
    does: the midpoint's half step, extrapolated); ``d_state`` the start's
    :class:`~fe_contact.stepping.step_derivative.StateDerivative`; each
    backward-Euler step's derivatives by
    :func:`~fe_contact.stepping.step_derivative.step_derivative`.
    Returns (state, d_state, outputs, d_outputs, the margins of each solve's
    contacts), or (status, message)."""
    where = f"step {state.step_index + 1}"
    if not report.converged:
        return report.status, f"{where}: {report.message}"
    if any(part[2].converged and "half steps" in part[2].message for part in taken):
        return Status.TANGENT_SINGULAR, (f"{where}: a load step taken in parts (its load half way, then the whole): "
                                         "its derivative through them is not available")
    middle = middle_load(model, state, step)
    w = 0.0
    if step.midpoint:
        if not taken or not taken[0][2].converged:
            return Status.TANGENT_SINGULAR, f"{where}: the midpoint's half step was not found"
        w = extrapolation_fraction(model, state, taken[0][1], taken[0][2], middle[0])
    if w > 0.0:  # the half step extrapolated by w: all of it, or then a backward-Euler step
        half = _rooted(model, taken[0], d_state, *middle, step, where)
        if isinstance(half[0], Status):
            return half
        if w == 1.0:
            return _extrapolated(model, new_state, report, d_state, half, step.d_start_out)
        return _partial(model, state, taken, new_state, report, d_state, half, w, step, where)
    loads = [middle, (step.load, step.d_load)] if step.midpoint else [(step.load, step.d_load)]
    if not chain or len(chain) != len(loads):
        return Status.TANGENT_SINGULAR, f"{where}: the parts it was taken in were not found"
    found = []
    for part, (load, d_load) in zip(chain, loads, strict=True):
        result = _rooted(model, part, d_state, load, d_load, step, where)
        if isinstance(result[0], Status):
            return result
        d_state = result[1]
        found.append(result[4])
    return new_state, d_state, report_outputs(report, new_state), result[3], found


def middle_load(model, state: State, step: LoadStep) -> tuple[float, np.ndarray]:
    """The midpoint's mid load ``P_m = (P_a + P_b) / 2``, N, and its derivative
    (J,): ``P_a`` the pad's load at ``state`` (as
    :func:`~fe_contact.stepping.midpoint.midpoint_half` takes it), ``dP_a =
    -dF_z`` the start's output (the step's own height, the last input, not in it)."""
    d_start_load = -np.array(step.d_start_out[step.force_z])
    d_start_load[-1] = 0.0
    return 0.5 * (pad_normal_load(model, state) + step.load), 0.5 * (d_start_load + step.d_load)


def _rooted(model, part, d_state, load: float, d_load: np.ndarray, step: LoadStep, where: str):
    """A backward-Euler load step ``part`` to ``load`` (``d_load`` (J,) its
    derivative): the step's sensitivity with its own height the last input,
    then that height the root of the load
    (:func:`load_step_root`), applied to
    the state, the outputs and the margins.  At ``load = 0`` the pad is open: its
    height does not move the block and its contacts are not checked.  A step that
    ended past a jump of the load (:mod:`~fe_contact.stepping.pad_load`: the pad let
    go at once, its load below the target) is no root: (status, message)."""
    start, _, report = part
    if load > 0 and missed_load(model, start, report, load):
        carried = -float(report.upper_force[2])
        return Status.TANGENT_SINGULAR, (f"{where}: a load step ended past a jump of the pad's load ({carried:.6g} N "
                                         f"for {load:.6g} N: the pad let go at once): its derivative is not available")
    for name in ("displacement", "pose", "plate"):
        getattr(d_state, name)[:, -1] = 0.0  # the last input: this step's own height
    if d_state.reaction is not None:
        d_state.reaction[..., -1] = 0.0
    d_command = np.zeros((4, d_state.pose.shape[1]))
    d_command[2, -1] = 1.0
    result = step_derivative(model, *part, d_state, d_command, step.seeds)
    if isinstance(result[0], Status):
        return result
    end, d_end, outputs, d_out, (m, dm, kind, skip) = result
    J = dm.shape[-1]
    d_out, arrays = load_step_root(d_out, step.force_z, load, d_load,
                                   (d_end.displacement, d_end.pose, d_end.plate, dm.reshape(-1, J),
                                    d_end.reaction.reshape(-1, J)))
    if load == 0:
        skip = skip | (np.arange(m.shape[0]) >= model.n_lower)
    d_end = replace(d_end, displacement=arrays[0], pose=arrays[1], plate=arrays[2],
                    reaction=arrays[4].reshape(d_end.reaction.shape))
    return end, d_end, outputs, d_out, (m, arrays[3].reshape(dm.shape), kind, skip)


def _extrapolated(model, new_state: State, report: StepReport, d_start, half, d_start_out: np.ndarray):
    """The midpoint's end ``S_b = 2 S_m - S_a`` from its half step's rooted
    derivatives ``half`` (:func:`_rooted`) and the start's ``d_start``,
    ``d_start_out`` (module docstring)."""
    _, d_mid, _, d_out_mid, found = half
    d_start_out = np.array(d_start_out)
    d_start_out[:, -1] = 0.0  # the start's own height is not an input of this step
    d_end = _ahead(half[0], d_start, d_mid, 1.0)
    d_out = np.vstack([lower_pose_derivative(model, new_state.displacement, d_end.displacement),
                       2.0 * d_out_mid[3:6] - d_start_out[3:6], d_end.plate])
    return new_state, d_end, report_outputs(report, new_state), d_out, [found]


def _ahead(middle: State, d_start, d_mid, w: float, moved=None):
    """The derivative of ``S_w = S_m + w (S_m - S_a)`` (:func:`~fe_contact.stepping.midpoint.partial_state`):
    ``dS_w = (1 + w) dS_m - w dS_a + (S_m - S_a) dw``, the last term where ``moved = (S_a, dw)``
    (``dw`` (J,))."""
    names = ("displacement", "pose", "plate") + (("reaction",) if d_start.reaction is not None else ())
    out = {name: (1.0 + w) * getattr(d_mid, name) - w * getattr(d_start, name) for name in names}
    if moved is not None:
        start, dw = moved
        pose = np.array([*(middle.upper_translation - start.upper_translation), middle.upper_rotation - start.upper_rotation])
        change = {"displacement": (middle.displacement - start.displacement).ravel(), "pose": pose,
                  "plate": middle.plate - start.plate, "reaction": middle.reaction - start.reaction}
        for name in names:
            out[name] = out[name] + np.multiply.outer(change[name], dw)
    return replace(d_mid, **out)


def _partial(model, state: State, taken: list, new_state: State, report: StepReport, d_state, half, w: float,
             step: LoadStep, where: str):
    """A midpoint load step whose half step was extrapolated by ``0 < w < 1`` and ended by a
    backward-Euler step from there (:func:`~fe_contact.stepping.midpoint.extrapolation_fraction`):
    ``dS_w`` with ``w``'s own derivative (:func:`_fraction_derivative`), then that step's
    rooted derivatives (:func:`_rooted`)."""
    middle, d_mid = taken[0][1], half[1]
    dw = _fraction_derivative(model, state, middle, w, (d_state, d_mid), step.seeds)
    if dw is None:
        return Status.TANGENT_SINGULAR, (f"{where}: the midpoint's extrapolation fraction {w:.6g} is set by two "
                                         "contacts at once (or their forces' derivatives are not followed): "
                                         "its derivative is not available")
    goal = new_state.displacement.tobytes()
    last = [part for part in taken[1:] if part[2].converged and part[1].displacement.tobytes() == goal]
    if not last:
        return Status.TANGENT_SINGULAR, f"{where}: the backward-Euler step after the extrapolation was not found"
    d_w = _ahead(middle, d_state, d_mid, w, (state, dw))
    result = _rooted(model, last[0], d_w, step.load, step.d_load, step, where)
    if isinstance(result[0], Status):
        return result
    return new_state, result[1], report_outputs(report, new_state), result[3], [half[4], result[4]]


def _fraction_derivative(model, state: State, middle: State, w: float, d_states: tuple, seeds: np.ndarray):
    """``dw`` (J,) of the extrapolation fraction ``w`` (< 1), set by one contact's bound
    (:func:`~fe_contact.stepping.midpoint.fraction_bounds`): its branch's function ``f`` (the
    normal force, the gap, or the cone's ``|M^-1 r_t|^2 - r_n^2``) of ``x(w) = x_m + w (x_m - x_a)``
    is 0 at ``w``, so ``dw = -(f'(x_w) ((1 + w) dx_m - w dx_a) + f_mu dmu) / f'(x_w) (x_m - x_a)``
    (``f_mu`` the cone's dependence on the floor's ``mu_x, mu_y``, ``dmu`` their ``seeds`` rows).
    ``d_states`` the derivatives of ``S_a`` and ``S_m``.  None where two bounds set it (a kink of
    the minimum) or the contact forces' derivatives are not followed."""
    d_start, d_mid = d_states
    bounds, kinds = fraction_bounds(model, state, middle)
    order = np.argsort(bounds)
    i = int(order[0])
    if d_start.reaction is None or (bounds.size > 1 and bounds[order[1]] - w <= 1e-9 * max(w, 1e-300)):
        return None
    if kinds[i] == "gap":
        node = model.contacts.nodes[i]
        normal = model.contacts.frames[i, 0]
        moving = model.contacts.bodies[model.contacts.body[i]].moves_with_gripper

        def gap(d):
            du = d.displacement.reshape(-1, 3, d.displacement.shape[1])[node]
            return normal @ (du - (d.pose[:3] if moving else 0.0))

        grad, da, dm, explicit = np.ones(1), gap(d_start)[None], gap(d_mid)[None], 0.0
        xa, xm = np.array([contact_gaps(model, state)[i]]), np.array([contact_gaps(model, middle)[i]])
    else:
        xa, xm = state.reaction[i], middle.reaction[i]
        da, dm = d_start.reaction[i], d_mid.reaction[i]
        grad, explicit = np.array([1.0, 0.0, 0.0]), 0.0
        if kinds[i] == "cone":
            mu = np.array([model.contacts.mu_x[i], model.contacts.mu_y[i]])
            x = xm + w * (xm - xa)
            grad = np.concatenate([[-2.0 * x[0]], 2.0 * x[1:] / mu ** 2])
            if i < model.n_lower:  # the floor's friction: a parameter
                explicit = (-2.0 * x[1:] ** 2 / mu ** 3) @ seeds[:2]
    return -(grad @ ((1.0 + w) * dm - w * da) + explicit) / (grad @ (xm - xa))
