"""``pushplan identify SCENARIO --observations FILE --out DIR``: estimate the friction
(``mu_x``, ``mu_y``, ``angle_deg``; ``young`` with ``--fit young``) from observed pushes,
write ``identified.json`` and ``identified.toml``; ``--suggest N`` proposes N pushes.

The scenario gives the block, mesh, material, solver and the initial friction; its
``[[load]]`` entries are not used (the observation file holds the executed commands).
Several observation files (``--observations A.csv B.csv``) are fitted together, each
run from its own press.  ``--suggest N`` also writes ``suggested_commands.json``, which
``pushplan simulate --commands`` runs as it is.  Exit status 0 when the fit converged
(its intervals in ``identified.json``; a reduced chi-square far above 1 is a warning),
3 when the fit failed (the files are written); 2 for bad input (nothing written).
"""

from __future__ import annotations

import sys

from ..errors import EXIT_SOLVER_FAILURE

IDENTIFY_FILES = ("identified.json", "identified.toml", "suggested_commands.json")
"""What ``identify`` writes in ``--out`` (one transaction)."""


def _print(result, doc) -> None:
    print(f"{'parameter':>10} {'initial':>10} {'estimate':>12} {'sigma':>10} {'95 % interval':>23}  identifiable")
    for k, p in doc["parameters"].items():
        sigma = "inf" if p["sigma"] is None else f"{p['sigma']:.4g}"
        lo, hi = p["interval_95"]
        interval = "unbounded" if lo is None or hi is None else f"[{lo:.5g}, {hi:.5g}]"
        print(f"{k:>10} {p['initial']:>10.5g} {p['estimate']:>12.6g} {sigma:>10} {interval:>23}  "
              + ("yes" if p["identifiable"] else f"no: {p['reason']}"))
    s = doc["solver"]
    print(f"  chi2 {doc['residual']['chi2']:.4g} for {doc['residual']['values']} values; "
          f"{s['iterations']} LM iterations, {s['fe_rollouts']} FE rollouts, {s['wall_time_s']:.2f} s")


def _commands_file(suggested: dict) -> dict:
    """``suggested_commands.json``: the suggested experiment as a bare ``commands`` list
    (no scenario fingerprint, so ``simulate --commands`` runs it on any block)."""
    return {"commands": suggested["commands"],
            "description": "pushplan identify --suggest: the press, then one push per suggested direction "
                           f"({', '.join(f'{d:g}' for d in suggested['directions_deg'])} deg from world x); "
                           "dx, dy, dz in m, dtheta_deg in degrees, each an increment of the upper face"}


def cmd_identify(args) -> int:
    from ..config import load_scenario
    from ..config.observations import read_observations
    from ..identify import NoiseModel, identify
    from ..identify.document import identified_document, identified_scenario
    from ..outputs import atomic_write_bytes, atomic_write_json
    from ..outputs.transaction import output_transaction
    from ..outputs.toml import toml_text

    scenario = load_scenario(args.scenario)
    obs = tuple(read_observations(path) for path in args.observations)
    noise = NoiseModel(args.pose_noise, args.force_noise, args.force_noise_rel, args.yaw_noise_deg,
                       args.force_resolution)
    for path, o in zip(args.observations, obs, strict=True):  # noise checks before anything is written
        _naming(path, noise.sigma, o, scenario.size)
    scenario.model()
    fit = ("mu_x", "mu_y", "angle_deg") + (("young",) if args.fit == "young" else ())
    log = None if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    with output_transaction(args.out, IDENTIFY_FILES) as tx:
        result = identify(scenario, obs, noise, fit, log=log, model_error=not args.no_model_error)
        sources = ", ".join(args.observations)
        doc = identified_document(result, scenario, obs, noise, sources)
        if args.suggest:
            from ..identify.design import suggest

            doc["suggested"] = _naming(args.observations[0], suggest, result.scenario(scenario), obs[0], noise,
                                       args.suggest, fit).to_dict()
            atomic_write_json(tx.path / "suggested_commands.json", _commands_file(doc["suggested"]))
        atomic_write_json(tx.path / "identified.json", doc)
        atomic_write_bytes(tx.path / "identified.toml", toml_text(
            identified_scenario(result, scenario), f"{scenario.name} with the friction identified by pushplan "
            f"identify from {sources}").encode())
    out = tx.out
    _print(result, doc)
    for w in doc["uncertainty"]["warnings"]:
        print(f"pushplan: warning: {w}", file=sys.stderr)
    if args.suggest:
        print(f"  suggested pushes (deg from world x): {doc['suggested']['directions_deg']}; "
              f"commands in {out / 'suggested_commands.json'} (for simulate --commands or a robot)")
    print(f"  wrote {out / 'identified.json'}, {out / 'identified.toml'}")
    if not result.converged:
        print("pushplan: the fit did not converge; the last iterate is written", file=sys.stderr)
        return EXIT_SOLVER_FAILURE
    return 0


def _naming(path, function, *args):
    """``function(*args)``, its :class:`InputError` about one observation file prefixed
    with the file's path (the messages of :mod:`pushplan.identify` know the table only)."""
    from ..errors import InputError

    try:
        return function(*args)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def add_noise_flags(p, yaw: bool = True) -> None:
    """``--pose-noise``, ``--force-noise``, ``--force-noise-rel``, ``--force-resolution``
    (and ``--yaw-noise-deg``), each a finite number in its stated range (:mod:`pushplan.limits`)."""
    from ..limits import MAX_FORCE_NOISE, MAX_FORCE_NOISE_REL, MAX_POSE_NOISE, MIN_POSE_NOISE, MIN_YAW_NOISE_DEG
    from .args import real

    p.add_argument("--pose-noise", type=real(MIN_POSE_NOISE, MAX_POSE_NOISE, closed_lo=True), default=1e-6,
                   help=f"pose noise, m ({MIN_POSE_NOISE} to {MAX_POSE_NOISE}; default 1e-6)")
    if yaw:
        p.add_argument("--yaw-noise-deg", type=real(MIN_YAW_NOISE_DEG, 180.0, closed_lo=True), default=None,
                       help="yaw noise, deg (default: the pose noise at half the face width)")
    p.add_argument("--force-noise", type=real(0.0, MAX_FORCE_NOISE, closed_lo=True), default=1.0,
                   help="absolute force noise, N (default 1)")
    p.add_argument("--force-noise-rel", type=real(0.0, MAX_FORCE_NOISE_REL, closed_lo=True), default=0.01,
                   help="force noise as a fraction of each observed value (default 0.01)")
    p.add_argument("--force-resolution", type=real(0.0, MAX_FORCE_NOISE), default=1e-3,
                   help="force sensor resolution, N: the smallest force sigma (default 1e-3)")


def register(subparsers) -> None:
    from ..limits import MAX_SUGGEST
    from .args import count

    p = subparsers.add_parser("identify", help="estimate the friction (mu_x, mu_y, angle) from observed pushes")
    p.add_argument("scenario", help="scenario TOML: block, mesh, material and the initial friction")
    p.add_argument("--observations", required=True, nargs="+", metavar="FILE",
                   help="observation files (.csv or .json), each from its own press")
    p.add_argument("--out", required=True, help="output folder (identified.json, identified.toml)")
    p.add_argument("--fit", choices=["young"], help="also estimate Young's modulus")
    add_noise_flags(p)
    p.add_argument("--no-model-error", action="store_true",
                   help="skip the refined-mesh rollout and the chi-square profile checks of the intervals (faster; "
                        "the intervals then hold the noise and the reduced chi-square only)")
    p.add_argument("--suggest", type=count(1, MAX_SUGGEST), metavar="N",
                   help=f"propose N push directions that identify the friction (at most {MAX_SUGGEST})")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_identify)
