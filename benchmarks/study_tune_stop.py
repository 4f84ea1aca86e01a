"""When may a continuation stage of the tuner stop? Wall time against the design's quality.

``hapid tune`` runs each continuation stage as a BFGS solve (optimistix) that stops when the
Cauchy test holds at ``rtol = atol = tol`` or after ``--max-steps`` steps
(``hapid.defaults.TUNE_TOL``). This study runs the default route (``hapid tune --model nls.npz
--frf frf.npz --fs FS``, loop draws) at several ``tol`` (every stage) on each device, then checks every design on that device's *true* plant with
``hapid analyze --device … --design …`` (the sampled loop). Devices: the presets and variants
given, each simulated with the paper protocol, fitted by NLS to 40 Hz.

Usage::

    python benchmarks/study_tune_stop.py --tols 1e-8 1e-4 1e-3 \
        --devices cu5 "cu5_soft" "quad4 --delay 2" --work /tmp/study_tune

Prints one row per (device, tol): wall time, stages, steps, claimed bandwidth, the design's
true-plant GM / PM / isotropic bandwidth and verdict. Results (JSON) go to ``--work``.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time

PY = sys.executable

# run the CLI with the BFGS tolerance of the tuner's stages replaced (the study's only knob)
_TUNE = """
import sys
import hapid.tune._tune as T
T.tune.__kwdefaults__["tol"] = float(sys.argv[1])  # every stage
T.tune.__kwdefaults__["tol_worst"] = float(sys.argv[1])
from hapid.cli import main
sys.exit(main(sys.argv[2:]))
"""


def run(cmd, log):
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        p = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT)
    if p.returncode != 0:
        raise SystemExit(f"failed ({p.returncode}): {shlex.join(cmd)}; see {log}")
    return time.perf_counter() - t0


def prepare(dev: str, work: str) -> str:
    """Simulate, FRF and NLS-fit one device; returns its directory."""
    name = dev.replace(" ", "").replace("--", "_")
    d = os.path.join(work, name)
    os.makedirs(d, exist_ok=True)
    if not os.path.exists(os.path.join(d, "nls.npz")):
        args = ["--device", *shlex.split(dev)]
        hp = [PY, "-m", "hapid"]
        run(hp + ["simulate", *args, "--out", f"{d}/run.npz"], f"{d}/sim.log")
        run(hp + ["frf", f"{d}/run.npz", "--out", f"{d}/frf.npz"], f"{d}/frf.log")
        run(hp + ["fit", f"{d}/frf.npz", "--method", "nls", "--out", f"{d}/nls.npz"],
            f"{d}/fit.log")  # fmt: skip
    return d


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tols", type=float, nargs="+", default=[1e-8, 1e-4, 1e-3])
    ap.add_argument("--devices", nargs="+", default=["cu5", "cu5_soft", "quad4 --delay 2"])
    ap.add_argument("--max-steps", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", default="out/study_tune_stop")
    a = ap.parse_args(argv)
    rows = []
    print("| device | tol | wall s | stages | steps | claimed Hz | true GM dB | true PM ° "
          "| true iso-bw Hz | true loop | decision |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for dev in a.devices:
        d = prepare(dev, a.work)
        for tol in a.tols:
            tag = f"{d}/tol{tol:g}_s{a.seed}"
            cmd = [PY, "-c", _TUNE, repr(tol), "tune", "--model", f"{d}/nls.npz",
                   "--frf", f"{d}/frf.npz", "--fs", "1000", "--out", f"{tag}.npz",
                   "--report", f"{tag}.json", "--max-steps", str(a.max_steps),
                   "--seed", str(a.seed), "--quiet"]  # fmt: skip
            wall = run(cmd, f"{tag}.log")
            rep = json.load(open(f"{tag}.json"))
            hist = rep.get("history", [])
            an = [PY, "-m", "hapid", "analyze", "--model", f"{d}/nls.npz", "--device",
                  *shlex.split(dev), "--design", f"{tag}.npz", "--out", f"{tag}_true.json"]  # fmt: skip
            run(an, f"{tag}_true.log")
            tr = json.load(open(f"{tag}_true.json"))
            row = dict(device=dev, tol=tol, wall_s=wall, stages=len(hist),
                       steps=sum(h["steps"] for h in hist),
                       claimed_hz=rep.get("bandwidth_claimed_hz"), true=tr)  # fmt: skip
            rows.append(row)
            print(f"| {dev} | {tol:g} | {wall:.0f} | {row['stages']} | {row['steps']} | "
                  f"{_f(row['claimed_hz'])} | {_f(tr.get('gm_db'))} | {_f(tr.get('pm_deg'))} | "
                  f"{_f(tr.get('iso_bandwidth_hz'))} | {tr.get('status')} | {rep.get('decision', '')[:60]} |",
                  flush=True)  # fmt: skip
    with open(os.path.join(a.work, f"rows_s{a.seed}.json"), "w") as fh:
        json.dump(rows, fh, indent=1, default=str)


def _f(x):
    return "—" if x is None else f"{x:.2f}"


if __name__ == "__main__":
    main()
