"""Speed of the native FONBW FMU in a C host, beside the pythonfmu FMU.

Builds FonbwHysteresisNative (and the pythonfmu FonbwHysteresis), compiles
fonbw/fmu/csrc/fmu_host.c with gcc, and reports the cost of a doStep
(setReal + doStep + getReal, one internal step per communication step) and of
the initialization (instantiate to exitInitializationMode), with the machine
load beside the figures. The pythonfmu FMU runs in the same host with the
environment it needs (LD_PRELOAD libpython, PYTHONPATH to site-packages).

    python benchmarks/bench_native_fmu.py [--steps N]
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import sysconfig
import tempfile
import zipfile
from pathlib import Path

from fonbw.fmu import native


def _extract(fmu: Path, dest: Path) -> tuple[Path, str]:
    zipfile.ZipFile(fmu).extractall(dest)
    guid = re.search(r'guid="([^"]+)"', (dest / "modelDescription.xml").read_text()).group(1)
    return dest, guid


def _python_env() -> dict:
    """What a non-Python host needs to run a pythonfmu FMU."""
    lib = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("LDLIBRARY")
    site = sysconfig.get_paths()["purelib"]
    return {"LD_PRELOAD": str(lib), "PYTHONPATH": site, "PYTHONHOME": sys.base_prefix,
            "PATH": "/usr/bin:/bin", "HOME": str(Path.home())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=1_000_000)
    ns = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fmu = native.build_native(tmp, kinds=["hysteresis"], platforms=["linux64"])[0]
        d, guid = _extract(fmu, tmp / "n")
        host = tmp / "fmu_host"
        subprocess.run(["gcc", "-std=c99", "-D_POSIX_C_SOURCE=200809L", "-O2", "-I", str(d / "sources"),
                        "-o", str(host), str(native.NATIVE_DIR / "fmu_host.c"), "-ldl", "-lm"], check=True)
        so = d / "binaries/linux64" / (fmu.stem + ".so")
        print(f"load average before: {os.getloadavg()}")
        r = subprocess.run(["env", "-i", str(host), "bench", str(so), guid, "", str(ns.steps)],
                           capture_output=True, text=True, check=True)
        nat = float(r.stdout.split()[0])
        print(f"native doStep: {nat:.1f} ns ({ns.steps} steps; target <= 300 ns); load {os.getloadavg()}")
        import time
        t0 = time.perf_counter()
        for _ in range(20):
            subprocess.run([str(host), "run", str(so), guid, "", "0"], check=True, capture_output=True)
        per = (time.perf_counter() - t0) / 20
        print(f"native process start + instantiate + initialize + free: {per * 1e3:.2f} ms "
              f"(target init <= 10 ms); load {os.getloadavg()}")
        py = _pythonfmu(tmp, host, ns.steps // 20)
        if py:
            print(f"pythonfmu doStep in the same host: {py:.0f} ns; ratio {py / nat:.0f}x; load {os.getloadavg()}")
    return 0


def _pythonfmu(tmp: Path, host: Path, steps: int) -> float | None:
    """ns per doStep of the pythonfmu FonbwHysteresis in the C host (None if it fails)."""
    r = subprocess.run([sys.executable, "-m", "fonbw.fmu.build", "--only", "hysteresis", "-o", str(tmp / "py")],
                       capture_output=True, text=True)
    if r.returncode != 0:
        print("pythonfmu build failed:", r.stderr[-500:])
        return None
    d, guid = _extract(tmp / "py" / "FonbwHysteresis.fmu", tmp / "pyx")
    so = d / "binaries/linux64/FonbwHysteresis.so"
    r = subprocess.run(["env", "-i", *(f"{k}={v}" for k, v in _python_env().items()), str(host), "bench",
                        str(so), guid, (d / "resources").as_uri(), str(steps)], capture_output=True, text=True)
    if "ns/step" not in r.stdout:
        print("pythonfmu FMU in the C host failed:", r.stderr[-500:])
        return None
    if r.returncode != 0:  # the known exit-time abort (fmu_src/README.md)
        print(f"pythonfmu host exited with {r.returncode} after the run: {r.stderr.strip()[-200:]}")
    return float(r.stdout.split()[0])


if __name__ == "__main__":
    sys.exit(main())
