"""The ``fonbw`` command line.

Every command validates its input at the boundary. On bad input it prints one
line ``fonbw <command>: error: <file>: <field/row>: <reason>`` on stderr and
exits with code 2, with no traceback, and without writing or half-writing
any output file (outputs are written atomically). Ctrl-C exits with code 130
and leaves previous outputs untouched.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

__all__ = ["main", "CLIError"]


class CLIError(Exception):
    """A user error reported as one line with exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse prints usage + message by default)
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


# ---------------------------------------------------------------------------
# helpers shared by the commands

def _model(path):
    from ..hysteresis import load_model

    return load_model(path)


def _records(paths, need=("u", "y"), zero=False):
    """Read records; with ``zero`` remove each one's sensor offset at rest (io.zero_at_rest)."""
    from ..io import read_record, zero_at_rest

    recs = [read_record(p, need=need) for p in paths]
    if not zero:
        return recs
    out = []
    for r in recs:
        r2, y0 = zero_at_rest(r)
        if y0:
            print(f"{r.path}: removed the offset at rest, {y0:.4g} µm", file=sys.stderr)
        out.append(r2)
    return out


def _out_path(path):
    d = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(d):
        raise CLIError(f"{path}: output directory {d} does not exist")
    return path


def _fmt(v):
    return f"{v:.6g}" if isinstance(v, float) else str(v)


# ---------------------------------------------------------------------------
# commands

def cmd_simulate(ns):
    from ..io import write_csv

    m = _model(ns.model)
    if ns.memory and hasattr(m, "memory"):
        from ..hysteresis import model_from_dict

        d = m.to_dict()
        d["params"]["memory"] = ns.memory
        m = model_from_dict(d, source=ns.model)
    (rec,) = _records([ns.input], need=("u",))
    y = m.simulate(rec.u, rec.dt)
    write_csv(_out_path(ns.output), {"t": rec.t, "u": rec.u, "y": y})
    print(f"wrote {ns.output}: {len(y)} samples at dt = {rec.dt:.6g} s, y in [{y.min():.4g}, {y.max():.4g}] µm")


def cmd_validate(ns):
    from ..reproduce import rms_metrics

    m = _model(ns.model)
    recs = _records(ns.data, zero=not ns.keep_offset)
    res = []
    for r in recs:
        met = rms_metrics(m, r)
        met.pop("yhat")
        res.append({"file": r.path, "samples": int(len(r.y)), **met})
    out = res[0] if len(res) == 1 else {"records": res, **{k: max(r[k] for r in res) for k in ("rms", "rms_percent", "max_abs")}}
    if ns.json:
        print(json.dumps({"model": ns.model, "kind": m.kind, **out}, indent=2))
    else:
        for r in res:
            print(f"{r['file']}: RMS {r['rms']:.4g} µm = {r['rms_percent']:.3g} % of range {r['range']:.4g} µm, "
                  f"max |error| {r['max_abs']:.4g} µm over {r['samples']} samples")


def cmd_identify(ns):
    from ..identify import identify

    recs = _records(ns.data, zero=not ns.keep_offset)
    if ns.seed is not None and ns.seed < 0:
        raise CLIError(f"--seed must be ≥ 0, got {ns.seed}")
    kw = dict(kind=ns.model, seed=ns.seed, progress=not ns.quiet)
    if ns.max_evals is not None:
        if ns.max_evals < 10:
            raise CLIError(f"--max-evals must be at least 10, got {ns.max_evals}")
        kw["max_evals"] = ns.max_evals
    if ns.workers is not None:
        if ns.workers < 1:
            raise CLIError(f"--workers must be ≥ 1, got {ns.workers}")
        kw["workers"] = ns.workers
    if ns.memory:
        kw["memory"] = ns.memory
    res = identify(recs, **kw)
    res.model.save(_out_path(ns.output))
    msg = getattr(res, "message", "")
    print(f"wrote {ns.output}: {res.model.kind} model, training RMS {res.rms:.4g} µm"
          + (f" ({msg})" if msg else ""))


def cmd_compensate(ns):
    from ..compensate import compensate_file

    if not ns.umin < ns.umax:
        raise CLIError(f"--umin ({ns.umin}) must be below --umax ({ns.umax})")
    res = compensate_file(ns.model, ns.trajectory, _out_path(ns.output), limits=(ns.umin, ns.umax),
                          explicit=ns.explicit)
    st = res.status
    low, high, nc = int((st == 1).sum()), int((st == 2).sum()), int((st == 3).sum())
    print(f"wrote {ns.output}: {len(res.u)} samples, u in [{res.u.min():.4g}, {res.u.max():.4g}] V; "
          f"{low} sample(s) at u_min, {high} at u_max, {nc} not converged")


def cmd_figures(ns):
    from ..figures import make_figures

    for p in make_figures(ns.output):
        print(f"wrote {p}")


def cmd_bench(ns):
    from ..bench import Bench

    b = Bench(seed=ns.seed)
    for p in b.write_experiments(ns.output, logger=True):
        print(f"wrote {p}")


def _delegate(module, func):
    """A command implemented in another module (`<module>.<func>(ns)`, `module` absolute)."""

    def run(ns):
        import importlib

        return getattr(importlib.import_module(module), func)(ns)

    return run


# ---------------------------------------------------------------------------

def build_parser(command=None) -> argparse.ArgumentParser:
    """The argument parser; ``command`` is the sub-command about to run (its
    arguments are attached only for it when defining them is costly)."""
    from .. import __version__
    from ..fractional import ENGINES

    p = _Parser(prog="fonbw", description="Fractional-order normalized Bouc-Wen hysteresis of piezoelectric "
                "actuators: simulate, identify, compensate, co-simulate FMUs, diagnose the sim-to-real gap.")
    p.add_argument("--version", action="version", version=f"fonbw {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    s = sub.add_parser("simulate", help="simulate a saved model on an input CSV (t,u)")
    s.add_argument("model", metavar="MODEL.json")
    s.add_argument("input", metavar="INPUT.csv")
    s.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    s.add_argument("--memory", choices=ENGINES, help="override the model's GL memory engine")
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("identify", help="identify a model from measured records (t,u,y) by jDE")
    s.add_argument("data", nargs="+", metavar="DATA.csv", help="one or more training records")
    s.add_argument("--model", choices=("fonbw", "cbw", "nbw", "zhu"), default="fonbw")
    s.add_argument("-o", "--output", required=True, metavar="MODEL.json")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--max-evals", type=int, dest="max_evals")
    s.add_argument("--workers", type=int)
    s.add_argument("--memory", choices=ENGINES)
    s.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    s.add_argument("--keep-offset", action="store_true",
                   help="do not remove the sensor offset at rest (mean y before the drive starts)")
    s.set_defaults(func=cmd_identify)

    s = sub.add_parser("validate", help="RMS / %% of range / max error of a model on records (t,u,y)")
    s.add_argument("model", metavar="MODEL.json")
    s.add_argument("data", nargs="+", metavar="DATA.csv")
    s.add_argument("--json", action="store_true", help="print a JSON object (keys rms, rms_percent, max_abs)")
    s.add_argument("--keep-offset", action="store_true",
                   help="do not remove the sensor offset at rest (mean y before the drive starts)")
    s.set_defaults(func=cmd_validate)

    s = sub.add_parser("compensate", help="feedforward input u for a desired trajectory (t,Hd), eq. (16)")
    s.add_argument("model", metavar="MODEL.json")
    s.add_argument("trajectory", metavar="TRAJ.csv")
    s.add_argument("-o", "--output", required=True, metavar="U.csv")
    s.add_argument("--umin", type=float, default=0.0, help="lower voltage limit [V] (default 0)")
    s.add_argument("--umax", type=float, default=120.0, help="upper voltage limit [V] (default 120)")
    s.add_argument("--explicit", action="store_true",
                   help="one-step-delayed variant instead of the per-step implicit solve")
    s.set_defaults(func=cmd_compensate)

    # cosim and diagnose define their own arguments; their modules pull in
    # python-control and fmpy (about a second), so they are imported only when
    # that command is the one being run.
    s = sub.add_parser("cosim", help="closed-loop co-simulation of the FMUs (reference, fmpy, libcosim)")
    if command == "cosim":
        from ..cosim import add_cosim_arguments

        add_cosim_arguments(s)
    s.set_defaults(func=_delegate("fonbw.cosim", "cosim_command"))

    s = sub.add_parser("diagnose", help="localize and attribute the sim-to-real gap")
    if command == "diagnose":
        from ..gap import add_diagnose_arguments

        add_diagnose_arguments(s)
    s.set_defaults(func=_delegate("fonbw.gap", "diagnose_command"))

    s = sub.add_parser("figures", help="the paper's Figs. 1-4 as PNG files")
    s.add_argument("-o", "--output", default="figures", metavar="DIR")
    s.set_defaults(func=cmd_figures)

    s = sub.add_parser("bench", help="write the virtual bench's experiments (eq. 19, sines, …) as CSV")
    s.add_argument("-o", "--output", default="bench-data", metavar="DIR")
    s.add_argument("--seed", type=int, default=0)
    s.set_defaults(func=cmd_bench)

    s = sub.add_parser("reproduce", help="the paper's Tables 1-4 and Figs. 8-11 on the virtual bench")
    s.add_argument("-o", "--output", default="reproduce-out", metavar="DIR")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--quick", action="store_true", help="small budgets (a smoke run)")
    s.set_defaults(func=_delegate("fonbw.demo", "reproduce_command"))

    s = sub.add_parser("demo", help="the whole workflow on the virtual bench, with an HTML report")
    s.add_argument("-o", "--output", default="demo-out", metavar="DIR")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--quick", action="store_true", help="reduced budgets (about a minute)")
    s.set_defaults(func=_delegate("fonbw.demo", "demo_command"))
    return p


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    command = next((a for a in args if not a.startswith("-")), None)
    parser = build_parser(command)
    ns = parser.parse_args(args)
    if not getattr(ns, "command", None):
        parser.print_help()
        return 2
    prog = f"fonbw {ns.command}"
    from ..io import DataError

    try:
        ns.func(ns)
    except (CLIError, DataError, ValueError, OSError) as exc:
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"{prog}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; no output was written", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
