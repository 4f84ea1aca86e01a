"""σ̄(T(jω) − I) with the paper's g(s) and with g tuned by gradients (hapid.tune).

Solid: the simulated cu5's true sampled plant with the discretized controller (what the
paper summary analyses). Shaded: 5–95 % band (line: median) over Laplace posterior samples
P̂_s of the NLS fit (continuous loops P̂_s · g Ẑ_T Ẑ_H⁻¹). Dotted: the 1 − 1/√2 threshold.

    python paper_figures/fig_tuned.py [--out out/paper] [--samples 200]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
TWO_PI = 2 * np.pi


def curves(samples: int = 200, seed: int = 7, cache=str(ROOT / ".hapid_cache" / "stages")):
    import hapid  # noqa: F401  (float64 first)
    from hapid import scene
    from hapid.control import (
        ISO_THRESHOLD,
        Compensator,
        discretize_controller,
        inverse_model_response,
    )
    from hapid.tune import posterior_plants
    from hapid.uncertainty import laplace_samples

    # the tuned g is the paper scene's "tuned" stage (cached with the other stages)
    res = scene.run_scene(scene.merge({}), ["device", "nls", "plant", "tuned"], cache_dir=cache,
                             out_dir=str(ROOT / "out" / "paper")).results  # fmt: skip
    dev, model, plant = res["device"], res["nls"]["model"], res["plant"]
    designs = {"paper g": Compensator.paper(), "tuned g": res["tuned"]["g"]}
    ps = laplace_samples(res["nls"]["result"], samples, key=seed)
    omc = TWO_PI * np.geomspace(0.1, 200.0, 300)
    Ps, _ = posterior_plants(ps.models(), omc)
    out = {
        "f_true": plant["omega"] / TWO_PI,
        "f_post": omc / TWO_PI,
        "threshold": float(ISO_THRESHOLD),
        "designs": {},
    }
    n = dev.n
    for name, g in designs.items():
        G = np.asarray(discretize_controller(model, g, dev.ts).at_omega(plant["omega"]))
        S = np.linalg.inv(np.eye(n) + plant["P"] @ G)
        true = np.linalg.svd(S, compute_uv=False)[:, 0]
        Gc = np.asarray(inverse_model_response(model, g, omc))
        Sp = np.linalg.inv(np.eye(n) + Ps @ Gc[None])
        sp = np.linalg.svd(Sp, compute_uv=False)[..., 0]
        out["designs"][name] = {"true": true, "q": np.quantile(sp, [0.05, 0.5, 0.95], axis=0)}
    return out


def plot(c, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for k, (name, d) in enumerate(c["designs"].items()):
        col = f"C{k}"
        ax.fill_between(c["f_post"], d["q"][0], d["q"][2], color=col, alpha=0.18, lw=0)
        ax.loglog(
            c["f_post"],
            d["q"][1],
            color=col,
            lw=0.8,
            ls="--",
            label=f"{name}: posterior median (5–95 % band)",
        )
        ax.loglog(
            c["f_true"], d["true"], color=col, lw=1.8, label=f"{name}: true plant (cu5, sampled)"
        )
    ax.axhline(c["threshold"], color="k", ls=":", lw=1, label="1 − 1/√2")
    ax.set_xlim(0.1, 200)
    ax.set_ylim(1e-3, 20)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("σ̄(T(jω) − I)")
    ax.set_title("σ̄(T − I): paper g(s) vs gradient-tuned g(s), NLS + PD model")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default=str(ROOT / "out" / "paper"))
    ap.add_argument("--samples", type=int, default=200)
    a = ap.parse_args()
    print(plot(curves(a.samples), Path(a.out) / "fig_tuned.png"))
