"""Virtual wall on cu5 (beyond the paper): penetration, force error, off-axis force and the
contact-stability limit for the MIMO (WLS, NLS models) and SISO loops; a figure of the
rendered wall force along and across the wall normal.

    python paper_figures/wall.py [--out out/paper] [--k-wall 200] [--push 2]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import hapid  # noqa: F401  (float64)
from hapid.control import (
    Compensator,
    discretize_compensator,
    discretize_controller,
    discretize_siso_controller,
    max_siso_gain,
)
from hapid.device import cu5
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.fit import fit_nls, positize, wls
from hapid.scene import analysis_grid, merge
from hapid.wall import (
    closed_loop_wall_steady_state,
    ideal_wall,
    max_wall_stiffness,
    perfect_control_wall,
    render_wall,
    wall_metrics,
)


def controllers(dev):
    frf = estimate_frf(periodic_run(dev, Protocol()))
    g = Compensator.paper()
    out = {"MIMO WLS": discretize_controller(positize(wls(frf)), g, dev.ts),
           "MIMO NLS": discretize_controller(fit_nls(frf).model, g, dev.ts)}  # fmt: skip
    omega = analysis_grid(merge({})["analysis"], dev.fs_hz)
    gd = discretize_compensator(g, dev.ts)
    c = float(
        max_siso_gain(
            np.asarray(dev.sampled_P(omega)), omega, np.asarray(gd.at_omega(omega)).reshape(-1)
        )
    )
    out[f"SISO c={c:.2f}"] = discretize_siso_controller(g, c, dev.ts, dev.n)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", default="out/paper")
    ap.add_argument("--k-wall", type=float, default=200.0)
    ap.add_argument("--push", type=float, default=2.0)
    a = ap.parse_args(argv)
    dev = cu5()
    ctrls = controllers(dev)
    rows = ["| axis | quantity | designer's wall | perfect control | " + " | ".join(ctrls) + " |",
            "|---|---|---|---|" + "---|" * len(ctrls)]  # fmt: skip
    sims = {}
    for ax, name in enumerate("xyz"):
        e = np.eye(dev.n)[ax]
        ide = ideal_wall(dev, e, a.k_wall, a.push)
        pc = perfect_control_wall(dev, e, a.k_wall, a.push).penetration
        pen, ferr, off, kmax = [], [], [], []
        for label, ct in ctrls.items():
            ss = closed_loop_wall_steady_state(dev, ct, e, a.k_wall, a.push)
            sim = render_wall(dev, ct, e, k_wall=a.k_wall, push=a.push, duration=6.0, wobble=0.3)
            sims[(name, label)] = sim
            m = wall_metrics(sim)
            pen.append(f"{ss.penetration * 1e3:.3f} ({100 * (ss.penetration / pc - 1):+.1f} %)")
            ferr.append(f"{100 * m.force_error:.1f} %")
            off.append(f"{m.off_axis_force:.1e}")
            kmax.append(f"{max_wall_stiffness(dev, ct, e):.0f}")
        rows.append(
            f"| {name} | steady penetration, mm (vs perfect control) | {ide * 1e3:.3f} | {pc * 1e3:.3f} | "
            + " | ".join(pen)
            + " |"
        )
        rows.append(f"| {name} | force error, probing hand | | | " + " | ".join(ferr) + " |")
        rows.append(f"| {name} | off-axis / on-axis force | | | " + " | ".join(off) + " |")
        rows.append(f"| {name} | max stable k_w, N/m | | | " + " | ".join(kmax) + " |")
    table = "\n".join(rows)
    print(
        f"cu5, paper g(s), k_w = {a.k_wall:g} N/m, push {a.push:g} N (probing: 30 % wobble at 1.5 Hz)\n"
    )
    print(table)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "wall.md").write_text(table + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 3, figsize=(12, 6), sharex=True)
    for j, name in enumerate("xyz"):
        for label in ctrls:
            sim = sims[(name, label)]
            e, F = sim.e, sim.F
            along = F @ e
            perp = np.linalg.norm((F - along[:, None] * e)[:, sim.translational], axis=1)
            axs[0, j].plot(sim.t, -along, label=label)
            axs[1, j].plot(sim.t, perp, label=label)
        axs[0, j].plot(sim.t, -(sim.F_d @ e), "k--", lw=0.8, label="commanded")
        axs[0, j].set_title(f"wall normal {name}")
        axs[1, j].set_xlabel("t (s)")
    axs[0, 0].set_ylabel("wall force along normal (N)")
    axs[1, 0].set_ylabel("force across normal (N)")
    axs[1, 0].set_yscale("log")
    axs[0, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "wall.png", dpi=120)
    print(f"\ntable → {out / 'wall.md'}, figure → {out / 'wall.png'}")


if __name__ == "__main__":
    main()
