"""Feedforward compensation of a desired trajectory with a saved model.

Reads TRAJ.csv (columns t [s] and Hd [µm]), inverts the model sample by
sample (eqs. (16)-(17): the input u [V] whose model output is Hd) and writes
U.csv with columns t [s], Hd [µm], u [V] and a per-sample status (0 solved,
1 at u_min, 2 at u_max, 3 not converged).
"""
from __future__ import annotations

from .records import CLIError, out_path


def add_arguments(p) -> None:
    from ..paper import U_RANGE

    p.add_argument("model", metavar="MODEL.json", help="model saved by identify")
    p.add_argument("trajectory", metavar="TRAJ.csv", help="desired trajectory: columns t [s], Hd [µm]")
    p.add_argument("-o", "--output", required=True, metavar="U.csv", help="where to write the input")
    p.add_argument("--umin", type=float, default=U_RANGE[0], help="lower voltage limit [V] (default %(default)g)")
    p.add_argument("--umax", type=float, default=U_RANGE[1], help="upper voltage limit [V] (default %(default)g)")
    p.add_argument("--explicit", action="store_true",
                   help="one-step-delayed variant instead of the per-step implicit solve")


def run(ns) -> None:
    from ..compensate import compensate_file

    if not ns.umin < ns.umax:
        raise CLIError(f"--umin ({ns.umin}) must be below --umax ({ns.umax})")
    res = compensate_file(ns.model, ns.trajectory, out_path(ns.output), limits=(ns.umin, ns.umax),
                          explicit=ns.explicit)
    st = res.status
    low, high, nc = int((st == 1).sum()), int((st == 2).sum()), int((st == 3).sum())
    print(f"wrote {ns.output}: {len(res.u)} samples, u in [{res.u.min():.4g}, {res.u.max():.4g}] V; "
          f"{low} sample(s) at u_min, {high} at u_max, {nc} not converged")
