"""Feedforward compensation of a desired trajectory with a saved model.

Reads TRAJ.csv (columns t [s] and Hd [µm]), inverts the model sample by
sample (eqs. (16)-(17): the input u [V] whose model output is Hd) and writes
U.csv with columns t [s], u [V], Hd [µm], y_model [µm] (the model's output
for that u) and a per-sample status (0 solved, 1 at u_min, 2 at u_max, 3 not
converged). With --preview the voltage starts ahead of the trajectory: those
pre-actuation rows come first, at times before the first of TRAJ.csv, with
status -1. A model identified after a rest cycle (its JSON's "start") is run
through that cycle first and its output counted from the end of it, as the
stage's sensor is zeroed at rest.
"""
from __future__ import annotations

import re
import sys

from .records import CLIError, add_record_arguments, load_model, out_path, read_records


def add_arguments(p) -> None:
    from ..paper import U_RANGE

    p.add_argument("model", metavar="MODEL.json", help="model saved by identify")
    p.add_argument("trajectory", metavar="TRAJ.csv", help="desired trajectory: columns t [s], Hd [µm]")
    p.add_argument("-o", "--output", required=True, metavar="U.csv", help="where to write the input")
    p.add_argument("--umin", type=float, default=None,
                   help="lower voltage limit [V] (default: the model's training input range, else %g)" % U_RANGE[0])
    p.add_argument("--umax", type=float, default=None,
                   help="upper voltage limit [V] (default: the model's training input range, else %g)" % U_RANGE[1])
    p.add_argument("--explicit", action="store_true",
                   help="one-step-delayed variant instead of the per-step implicit solve")
    p.add_argument("--preview", action="store_true",
                   help="invert the whole known trajectory at once (non-causal, stable for any identified "
                        "model, invertible or not; the voltage starts ahead of the trajectory, rows with "
                        "negative status); without it the causal per-step inverse that an FMU "
                        "or a real-time loop runs")
    add_record_arguments(p, offset=False, y=True)


def run(ns) -> None:
    import warnings

    from ..compensate import compensate, default_limits
    from ..compensate.causal import output_columns
    from ..io import write_csv

    out = out_path(ns.output, (ns.model, ns.trajectory))
    model = load_model(ns.model)
    lo, hi = default_limits(model)
    lo = lo if ns.umin is None else ns.umin
    hi = hi if ns.umax is None else ns.umax
    if not lo < hi:
        raise CLIError(f"--umin ({lo:g} V) must be below --umax ({hi:g} V)")
    (rec,) = read_records([ns.trajectory], ns, need=("Hd",))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        res = compensate(model, rec.hd, rec.dt, limits=(lo, hi), explicit=ns.explicit, preview=ns.preview)
    for line in _warning_lines(caught):
        print(f"fonbw compensate: warning: {line}", file=sys.stderr)
    write_csv(out, output_columns(model, res, rec.t))
    c = res.counts
    print(f"wrote {ns.output}: {len(res.u)} samples, u in [{res.u.min():.4g}, {res.u.max():.4g}] V "
          f"(limits {lo:g}..{hi:g} V); {c['saturated_low']} sample(s) at u_min, {c['saturated_high']} at u_max, "
          f"{c['not_converged']} not converged")
    if res.tracking_impossible:
        raise CLIError(f"{ns.trajectory}: cannot track the trajectory: {res.tracking_impossible} "
                       f"(the input written to {ns.output} is the closest the model allows)")


def _warning_lines(caught):
    """The warnings `caught` as lines to print, numpy's floating-point ones
    (a model that overflows on the trajectory raises one per operation and
    sample block) folded into one line that says what they mean."""
    lines, fp = [], {}
    for w in caught:
        text = " ".join(str(w.message).split())
        # numpy's own wording, also "... in scalar multiply" for scalars
        if re.fullmatch(r"(overflow|invalid value|divide by zero|underflow) encountered in [\w ]+", text):
            fp[text] = fp.get(text, 0) + 1
        elif text not in lines:
            lines.append(text)
    if fp:
        seen = ", ".join(f"{k} ×{n}" if n > 1 else k for k, n in fp.items())
        lines.insert(0, f"the model's arithmetic overflowed or gave values that are not numbers on this "
                        f"trajectory (numpy: {seen}); check its parameters")
    return lines
