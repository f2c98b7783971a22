"""Feedforward compensation of a desired trajectory with a saved model.

Reads TRAJ.csv (columns t [s] and Hd [µm]), inverts the model sample by
sample (eqs. (16)-(17): the input u [V] whose model output is Hd) and writes
U.csv with columns t [s], u [V], Hd [µm], y_model [µm] (the model's output
for that u) and a per-sample status (0 solved, 1 at u_min, 2 at u_max, 3 not
converged).
"""
from __future__ import annotations

from .records import CLIError, add_record_arguments, load_model, out_path, read_records


def add_arguments(p) -> None:
    from ..paper import U_RANGE

    p.add_argument("model", metavar="MODEL.json", help="model saved by identify")
    p.add_argument("trajectory", metavar="TRAJ.csv", help="desired trajectory: columns t [s], Hd [µm]")
    p.add_argument("-o", "--output", required=True, metavar="U.csv", help="where to write the input")
    p.add_argument("--umin", type=float, default=U_RANGE[0], help="lower voltage limit [V] (default %(default)g)")
    p.add_argument("--umax", type=float, default=U_RANGE[1], help="upper voltage limit [V] (default %(default)g)")
    p.add_argument("--explicit", action="store_true",
                   help="one-step-delayed variant instead of the per-step implicit solve")
    add_record_arguments(p, offset=False, y=True)


def run(ns) -> None:
    from ..compensate import compensate
    from ..io import write_csv

    if not ns.umin < ns.umax:
        raise CLIError(f"--umin ({ns.umin}) must be below --umax ({ns.umax})")
    model = load_model(ns.model)
    (rec,) = read_records([ns.trajectory], ns, need=("Hd",))
    res = compensate(model, rec.hd, rec.dt, limits=(ns.umin, ns.umax), explicit=ns.explicit)
    write_csv(out_path(ns.output), {"t": rec.t, "u": res.u, "Hd": res.Hd, "y_model": res.y_model,
                                    "status": res.status.astype(float)})
    st = res.status
    low, high, nc = int((st == 1).sum()), int((st == 2).sum()), int((st == 3).sum())
    print(f"wrote {ns.output}: {len(res.u)} samples, u in [{res.u.min():.4g}, {res.u.max():.4g}] V; "
          f"{low} sample(s) at u_min, {high} at u_max, {nc} not converged")
