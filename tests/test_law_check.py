"""Issue 43: a step is reported converged only when its floor contacts hold the contact law
(fe_contact/stepping/law_check.py): Signorini (no penetration, no adhesion, no force off the
floor) and the elliptic Coulomb cone, each to LAW_TOL of the block's size or force."""

from dataclasses import replace

import numpy as np
import pytest

import fe_contact.stepping.held as held
from fe_contact import Command, build_model, initial_state, step
from fe_contact.stepping.law_check import LAW_TOL, law_violation
from fe_contact.stepping.report import Status


@pytest.fixture(scope="module")
def pushed():
    """A 2 x 2 x 1 rubber-like block (20 x 20 x 10 mm) pressed 0.1 mm and pushed 0.3 mm
    on an anisotropic floor (0.6 / 0.2 at 30 deg): some nodes stick, some slide."""
    model = build_model((0.02, 0.02, 0.01), (2, 2, 1), 5e6, 0.3, 0.6, 0.2, angle=np.radians(30.0), quadrature=2)
    s, press = step(model, initial_state(model), Command(dz=-1e-4))
    _, push = step(model, s, Command(dx=3e-4))
    assert press.converged and push.converged
    return model, push


def test_a_converged_step_holds_the_law_far_inside_its_tolerance(pushed):
    model, rep = pushed
    assert law_violation(model, rep) == ""
    L, R = max(model.mesh.size), np.abs(rep.reaction_local).max()
    assert -rep.gap.min() / L < 1e-3 * LAW_TOL
    cone = np.hypot(rep.reaction_local[:, 1] / 0.6, rep.reaction_local[:, 2] / 0.2) - rep.reaction_local[:, 0]
    assert cone.max() / R < 1e-3 * LAW_TOL
    assert rep.n_slip > 0  # on the cone's surface somewhere: the cone check is not vacuous


@pytest.mark.parametrize("broken, what", [
    (lambda m, r: replace(r, gap=r.gap - 10 * LAW_TOL * max(m.mesh.size)), "penetration"),
    (lambda m, r: replace(r, reaction_local=r.reaction_local * [[-1, 1, 1]]), "adhesion"),
    (lambda m, r: replace(r, reaction_local=r.reaction_local * [[1, 1.01, 1.01]]), "outside the cone"),
    (lambda m, r: replace(r, gap=r.gap + 10 * LAW_TOL * max(m.mesh.size)), "off the floor"),
])
def test_each_part_of_the_law_is_checked(pushed, broken, what):
    model, rep = pushed
    assert what in law_violation(model, broken(model, rep))


def test_a_step_whose_last_iterate_breaks_the_law_is_not_converged(pushed, monkeypatch):
    """The step's own pipeline applies the check: a converged equilibrium measured with the
    lower face 0.1 um inside the floor (as the mu = 1e7 press once was) fails, and the step
    returns its input state."""
    model, _ = pushed
    measure = held.measure

    def sunk(*args, **kwargs):
        rep = measure(*args, **kwargs)
        return replace(rep, gap=rep.gap - 1e-7)

    monkeypatch.setattr(held, "measure", sunk)
    state = initial_state(model)
    new, rep = step(model, state, Command(dz=-1e-4))
    assert rep.status is Status.CONTACT_NOT_CONVERGED and "penetration" in rep.message
    assert new is state
