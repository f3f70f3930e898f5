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
"""

from __future__ import annotations

import numpy as np

from .model import Model, State
from .sequence import StepSequence
from .step import half_command, step

__all__ = ["RecordingSequence", "load_step_root", "put_down_root", "release_height_derivative", "whole_steps"]


class RecordingSequence(StepSequence):
    """:class:`~fe_contact.stepping.sequence.StepSequence` that keeps the steps it
    takes since the last one it yielded (the parts a step was taken in), and
    a step's derivative follows the parts that were kept."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.taken = []

    def _step(self, model, state, command, consume=False):
        out = super()._step(model, state, command, consume=consume)
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

