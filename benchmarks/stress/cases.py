"""Numerical stress cases for hapid (issue 7): each states what hapid does.

Every case function returns a list of rows ``{"case", "setting", "expected", "measured",
"outcome", "ok"}``. ``outcome`` is one of

- ``right answer`` — the result is correct to the stated accuracy;
- ``clear warning`` — the result may be poor, and hapid says so (warning, status, flag);
- ``clear error`` — hapid refuses with an error that names the problem;
- ``measured`` — a number the issue asked for (e.g. float32 error growth), no verdict;
- ``SILENT FAILURE`` — a NaN or a wrong number with no warning (``ok`` is False).

``fast=True`` shrinks sizes so ``tests/test_stress.py`` can run the same code in seconds.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "tests"))  # oracle_loop
from oracle_loop import analyze_loop  # noqa: E402  (the LAPACK reference loop analysis)

import hapid  # noqa: E402
from hapid import ImpedanceModel, SecondOrder
from hapid._constants import TWO_PI
from hapid.control import StateSpace, closed_loop_poles
from hapid.experiment import Protocol, estimate_frf, patterns, periodic_run
from hapid.fit import (
    Scale,
    crhp_report,
    data_scale,
    fit_nls,
    make_problem,
    model_to_theta,
    n_params,
    positize,
    project_pd,
    theta_to_model,
    wls,
    wls_coefficients,
)

PAPER_HZ = np.concatenate([np.arange(1.0, 11.0), np.arange(15.0, 101.0, 5.0)])
OUTCOMES = ("right answer", "clear warning", "clear error", "measured", "SILENT FAILURE")


# ---------------------------------------------------------------------------------------
# building blocks
# ---------------------------------------------------------------------------------------


def spd(rng, n, eigs):
    """Symmetric matrix ``Q diag(eigs) Qᵀ`` with a random rotation ``Q``."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.asarray(eigs, dtype=float)) @ Q.T


def truth_model(n, seed=0, m_hand=(0.1, 1.0)) -> ImpedanceModel:
    """Hand and mechanism with SPD M (kg), B (N·s/m), K (N/m), eigenvalues log-spaced."""
    rng = np.random.default_rng(seed)
    g = lambda lo, hi: np.geomspace(lo, hi, n)  # noqa: E731
    hand = SecondOrder(
        jnp.asarray(spd(rng, n, g(*m_hand))),
        jnp.asarray(spd(rng, n, g(2.0, 30.0))),
        jnp.asarray(spd(rng, n, g(3e2, 3e3))),
    )
    mech = SecondOrder(
        jnp.asarray(spd(rng, n, g(0.3, 0.8))),
        jnp.asarray(spd(rng, n, g(10.0, 40.0))),
        jnp.asarray(spd(rng, n, g(1e2, 5e2))),
    )
    return ImpedanceModel.from_hand_mechanism(hand, mech)


def model_frf(truth: ImpedanceModel, freq_hz, snr_db=None, seed=1):
    """FRF of ``truth`` with complex noise of std ``‖Z(jω)‖_F/n · 10^(−snr/20)`` per element
    (``snr_db=None``: noise-free, stds omitted)."""
    rng = np.random.default_rng(seed)
    w = TWO_PI * np.asarray(freq_hz)
    out = []
    for Z in (np.asarray(truth.hand.at_omega(w)), np.asarray(truth.total.at_omega(w))):
        if snr_db is None:
            out.append((Z, None))
            continue
        n = Z.shape[-1]
        std = np.linalg.norm(Z, axis=(-2, -1))[:, None, None] / n * 10 ** (-snr_db / 20)
        std = np.broadcast_to(std, Z.shape).copy()
        noise = (rng.standard_normal(Z.shape) + 1j * rng.standard_normal(Z.shape)) / np.sqrt(2)
        out.append((Z + std * noise, std))
    (ZH, sH), (ZT, sT) = out
    return hapid.as_frf(freq_hz, ZH, ZT, sH, sT)


def mats(model: ImpedanceModel):
    h, m = model.hand, model.mechanism
    return [np.asarray(a) for a in (h.M, h.B, h.K, m.M, m.B, m.K)]


def model_err(model: ImpedanceModel, truth: ImpedanceModel) -> float:
    """Largest relative Frobenius error over the six hand/mechanism matrices."""
    return max(
        float(np.linalg.norm(a - b) / np.linalg.norm(b))
        for a, b in zip(mats(model), mats(truth), strict=True)
    )


def row(case, setting, expected, measured, outcome, ok=None):
    assert outcome in OUTCOMES, outcome
    ok = (outcome != "SILENT FAILURE") if ok is None else ok
    return dict(
        case=case, setting=setting, expected=expected, measured=measured, outcome=outcome, ok=ok
    )


def caught(fn):
    """``(value, [warning messages])`` of ``fn()`` with every warning recorded."""
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = fn()
    return out, [str(x.message) for x in w]


def match_roots(a, b):
    """Largest relative distance between two root sets under the best pairing."""
    from scipy.optimize import linear_sum_assignment

    a, b = np.asarray(a), np.asarray(b)
    C = np.abs(a[:, None] - b[None, :])
    r, c = linear_sum_assignment(C)
    return float(np.max(C[r, c] / np.maximum(np.abs(b[c]), 1e-300)))


def pencil_roots(so: SecondOrder):
    """Reference roots of det(M s² + B s + K) from scipy's generalized eigenvalues."""
    import scipy.linalg as sl

    M, B, K = (np.asarray(x) for x in (so.M, so.B, so.K))
    n = M.shape[0]
    I, Z = np.eye(n), np.zeros((n, n))
    return sl.eigvals(np.block([[Z, I], [-K, -B]]), np.block([[I, Z], [Z, M]]))


def pencil_crhp(so: SecondOrder, tol: float = 0.0) -> int:
    """Reference closed-RHP root count of det(M s² + B s + K) (scipy's generalized
    eigenvalues; roots at ∞ counted, as hapid does) — independent of ``SecondOrder.roots``."""
    r = pencil_roots(so)
    return int(np.sum(~np.isfinite(r)) + np.sum(np.real(r[np.isfinite(r)]) >= -tol))


def nls_outcome(res, err: float, tol: float, truth) -> tuple[str, bool]:
    """Outcome of an NLS fit against its known truth. Converged: right answer iff the error
    is below ``tol``. Not converged: the status says so, but that alone is not enough — it
    counts as a clear warning only if the fit still carries honest uncertainty (≥ 80 % of the
    model entries within 3 reported Laplace std of the truth) or is within ``tol`` anyway;
    otherwise it is a wrong number. Returns ``(outcome, honest)``."""
    if res.ok:
        return ("right answer" if err < tol else "SILENT FAILURE"), err < tol
    cover, _ = _coverage(res, truth)
    honest = err < tol or cover >= 0.8
    return ("clear warning" if honest else "SILENT FAILURE"), honest


# ---------------------------------------------------------------------------------------
# 1. float32 vs float64
# ---------------------------------------------------------------------------------------


def case_float32_input(fast=False):
    """float32/complex64 FRF arrays: upcast to float64 with a PrecisionWarning."""
    truth = truth_model(3, seed=0)
    f64 = model_frf(truth, PAPER_HZ)
    arr32 = [np.asarray(a).astype(t) for a, t in ((f64.freq_hz, np.float32),
             (f64.Z_H, np.complex64), (f64.Z_T, np.complex64))]  # fmt: skip
    frf32, msgs = caught(lambda: hapid.as_frf(*arr32))
    warned = any("upcast" in m for m in msgs)
    dtypes = {str(frf32.omega.dtype), str(frf32.Z_H.dtype), str(frf32.Z_T.dtype)}
    e64, e32 = model_err(wls(f64), truth), model_err(wls(frf32), truth)
    ok = warned and dtypes == {"float64", "complex128"} and e32 < 1e-5
    return [
        row(
            "float32 input",
            "as_frf(float32 freq, complex64 Z), n=3, paper grid, noise-free; WLS",
            "upcast to float64 with a warning",
            f"PrecisionWarning={warned}, dtypes {sorted(dtypes)}; WLS err {e64:.1e} (float64 "
            f"data) vs {e32:.1e} (float32 data)",
            "clear warning" if ok else "SILENT FAILURE",
        )
    ]


def _float32_arith_rows(name, freq_hz, truth):
    frf = model_frf(truth, freq_hz)
    w, Z = np.asarray(frf.omega), np.asarray(frf.Z_T)
    ref = np.stack([np.asarray(a) for a in (truth.total.M, truth.total.B, truth.total.K)])

    def err(th):
        return max(np.linalg.norm(th[k] - ref[k]) / np.linalg.norm(ref[k]) for k in range(3))

    out = {}
    for dt, cdt in ((np.float64, np.complex128), (np.float32, np.complex64)):
        th = np.asarray(wls_coefficients(jnp.asarray(w, dt), jnp.asarray(Z, cdt)))
        # the paper's literal normal equations, without hapid's column scaling
        s = 1j * w
        h = 1 / (s + 7 * TWO_PI) ** 2
        A = (h[:, None] * np.stack([s**2, s, np.ones_like(s)], 1)).astype(cdt)
        G = np.real(A.conj().T @ A).astype(dt)
        rhs = np.real(A.conj().T @ (h[:, None] * Z.reshape(len(w), -1)).astype(cdt)).astype(dt)
        th2 = np.linalg.solve(G, rhs).reshape(ref.shape)
        # no weight at all: columns s², s, 1 span (2π f_max)⁴ in the normal matrix
        A0 = np.stack([s**2, s, np.ones_like(s)], 1).astype(cdt)
        G0 = np.real(A0.conj().T @ A0).astype(dt)
        r0 = np.real(A0.conj().T @ Z.reshape(len(w), -1).astype(cdt)).astype(dt)
        with np.errstate(all="ignore"):
            th3 = np.linalg.lstsq(G0, r0, rcond=None)[0].reshape(ref.shape)
        out[dt] = (err(th), err(th2), err(th3), np.linalg.cond(np.asarray(G, float)),
                   np.linalg.cond(np.asarray(G0, float)))  # fmt: skip
    so = truth.total
    so32 = SecondOrder(*(jnp.asarray(x, jnp.float32) for x in (so.M, so.B, so.K)))
    r_err = match_roots(np.asarray(so32.roots()), pencil_roots(so))
    a, b = out[np.float64], out[np.float32]
    return row(
        "float32 arithmetic",
        f"{name}: WLS in float32 vs float64, Z_T of a 3-rod truth, noise-free",
        "error ≈ ε₃₂·κ (ε₃₂ = 6e-8); measured, not a user mode",
        f"scaled WLS {a[0]:.0e}→{b[0]:.0e}; paper normal eq. (κ={a[3]:.0e}) {a[1]:.0e}→"
        f"{b[1]:.0e}; unweighted (κ={a[4]:.0e}) {a[2]:.0e}→{b[2]:.0e}; roots in float32 "
        f"{r_err:.0e}",
        "measured",
    )


def case_float32_arith(fast=False):
    truth = truth_model(3, seed=0)
    rows = [_float32_arith_rows("paper grid 1–100 Hz", PAPER_HZ, truth)]
    if not fast:
        rows.append(_float32_arith_rows("0.1 Hz–1 kHz", np.geomspace(0.1, 1000, 80), truth))
        stiff = truth_model(3, seed=0, m_hand=(1e-6, 1.0))
        rows.append(_float32_arith_rows("stiff (M ratio 1e6)", PAPER_HZ, stiff))
    return rows


_X64_OFF = """
import warnings, numpy as np, jax
import hapid
jax.config.update("jax_enable_x64", False)
try:
    hapid.as_frf(np.array([1.0, 2.0, 3.0]), np.ones((3, 2, 2)), np.ones((3, 2, 2)))
    print("NO ERROR")
except RuntimeError as e:
    print("RuntimeError:", e)
"""


def case_x64_off(fast=False):
    """JAX float64 switched off after ``import hapid``: a clear error, not a float32 run."""
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", _X64_OFF], capture_output=True, text=True,
                         env=env, timeout=300)  # fmt: skip
    msg = (out.stdout + out.stderr).strip().splitlines()
    last = msg[-1] if msg else ""
    ok = last.startswith("RuntimeError") and "jax_enable_x64" in last
    return [
        row(
            "float32 everywhere",
            "subprocess: import hapid, then jax_enable_x64=False; as_frf(...)",
            "clear error (hapid is float64)",
            last[:110],
            "clear error" if ok else "SILENT FAILURE",
        )
    ]


# ---------------------------------------------------------------------------------------
# 2. frequency grids 0.1 Hz – 1 kHz, NLS with and without scaling
# ---------------------------------------------------------------------------------------


@functools.partial(jax.jit, static_argnums=(2,))
def _lm_jit(problem, theta0, max_steps):
    from hapid.fit import DEFAULT_SOLVER
    from hapid.fit._solvers import run_solver

    return run_solver(problem, theta0, DEFAULT_SOLVER, max_steps, 1e-8, 20)


def _lm_run(problem, theta0, max_steps=400):
    """fit_nls's Levenberg–Marquardt on a given Problem (any Scale); one compile per shape."""
    theta, steps, code = _lm_jit(problem, theta0, max_steps)
    return theta, int(steps), ("converged", "max_steps", "failed")[int(code)]


def case_wide_grid(fast=False):
    n = 3
    truth = truth_model(n, seed=2)
    N = 40 if fast else 200
    f = np.geomspace(0.1, 1000.0, N)
    rows = []
    frf0 = model_frf(truth, f)
    e = model_err(wls(frf0), truth)
    rows.append(row("wide grid: WLS", f"0.1 Hz–1 kHz, {N} log-spaced, noise-free, n={n}",
                    "exact (rounding)", f"max rel. err {e:.1e}",
                    "right answer" if e < 1e-8 else "SILENT FAILURE"))  # fmt: skip
    frf = model_frf(truth, f, snr_db=60, seed=3)
    start = project_pd(wls(frf), floor=1e-6)
    for label, scale in (("data_scale (default)", data_scale(frf, None)),
                         ("no scaling (Scale(1, 1))", Scale.identity())):  # fmt: skip
        prob = make_problem(frf, f_max_hz=None, scale=scale)
        th0 = model_to_theta(start, scale)
        J = np.asarray(jax.jacfwd(prob)(th0))
        sv = np.linalg.svd(J, compute_uv=False)
        t0 = time.perf_counter()
        th, steps, status = _lm_run(prob, th0)
        dt = time.perf_counter() - t0
        err = model_err(theta_to_model(th, scale), truth)
        # converged: within 1e-2 of the truth; not converged: the status says so, and the
        # iterate must still be near the truth (1e-1) — a far-off number is wrong either way
        if status == "converged":
            outcome = "right answer" if err < 1e-2 else "SILENT FAILURE"
        else:
            outcome = "clear warning" if err < 1e-1 else "SILENT FAILURE"
        rows.append(row(f"wide grid: NLS, {label}",
                        f"0.1 Hz–1 kHz, {N} freqs, SNR 60 dB, relative weights, all freqs",
                        "converged, err ≲ 1e-3 (scaled)",
                        f"cond(J₀) {sv[0] / sv[-1]:.1e}; {status} in {steps} steps "
                        f"({dt:.1f} s); err {err:.1e}", outcome))  # fmt: skip
    if fast:  # same LM as the scaled row above; fit_nls adds its own compile
        return rows
    res = fit_nls(frf, f_max_hz=None)
    err = model_err(res.model, truth)
    rows.append(row("wide grid: fit_nls", "same data, fit_nls(f_max_hz=None)",
                    "converged, small error", f"{res.status} in {int(res.n_steps)} steps, "
                    f"err {err:.1e}", nls_outcome(res, err, 1e-2, truth)[0]))  # fmt: skip
    return rows


# ---------------------------------------------------------------------------------------
# 3. ill-conditioned excitation
# ---------------------------------------------------------------------------------------


def _sod(n, seed=0):
    from hapid.device import SecondOrderDevice

    t = truth_model(n, seed)
    return SecondOrderDevice(hand=t.hand, mechanism=t.mechanism)


def _rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def case_excitation(fast=False):
    from hapid.device import cu5

    rows = []
    dev = cu5() if not fast else _sod(5)
    name = "cu5" if not fast else "5-rod second-order device"
    errs = {}
    for pat in ("paper", "one_at_a_time"):
        frf, msgs = caught(
            lambda pat=pat: estimate_frf(periodic_run(dev, Protocol(pattern=pat, n_periods=2)))
        )  # noqa: E501
        ZH, ZT = dev.sampled_impedances(frf.omega)
        errs[pat] = (float(np.max(frf.cond_L)), _rel(frf.Z_H, ZH), _rel(frf.Z_T, ZT), msgs)
    c, eh, et, msgs = errs["one_at_a_time"]
    cp, ehp, etp, _ = errs["paper"]
    rows.append(row("one rod at a time", f"{name}, default noise, 2 periods",
                    "warn if cond(𝓛) > 1e3, else a usable estimate",
                    f"cond(𝓛) ≤ {c:.1f} (paper pattern {cp:.1f}); Z_H err {eh:.3f}, Z_T err "
                    f"{et:.3f} (paper pattern {ehp:.3f}, {etp:.3f}); warnings: {len(msgs)}",
                    "right answer" if c < 1e3 and not msgs else "clear warning"))  # fmt: skip

    sod = _sod(5)
    U = np.array(patterns(5, "paper"))
    for eps, pn in ((1e-3, 0.0), (1e-6, 1e-4)):
        V = U.copy()
        V[2] = V[0] + V[1] + eps * U[2]
        prot = Protocol(pattern=tuple(map(tuple, V)), n_periods=4, encoder_resolution=0.0,
                        position_noise=pn)  # fmt: skip
        frf, msgs = caught(lambda prot=prot: estimate_frf(periodic_run(sod, prot)))
        ZH, ZT = sod.sampled_impedances(frf.omega)
        err = _rel(frf.Z_T, ZT)
        sd = np.asarray(frf.Z_T_std)
        e_abs = np.abs(np.asarray(frf.Z_T) - np.asarray(ZT))
        cover = float(np.max(e_abs / sd)) if np.all(sd > 0) else float("nan")
        warned = any("poorly conditioned" in m or "nearly dependent" in m for m in msgs)
        kinds = sorted({"cond(𝓛)" if "poorly" in m else "cond(𝓡_A)" for m in msgs})
        rows.append(row("nearly dependent patterns",
                        f"row3 = row1 + row2 + {eps:g}·row3, position noise {pn:g} m",
                        "warning (cond(𝓛) or cond(𝓡_A) > 1e3); std covers the error",
                        f"Z_T err {err:.2g}, max |err|/std "
                        f"{'n/a (std 0: noise-free)' if np.isnan(cover) else f'{cover:.1f}'}; warned on {kinds}",
                        "clear warning" if warned else "SILENT FAILURE"))  # fmt: skip
    V = U.copy()
    V[2] = V[0] + V[1]
    try:
        Protocol(pattern=tuple(map(tuple, V))).pattern_matrix(5)
        rows.append(row("dependent patterns", "row3 = row1 + row2", "error", "accepted",
                        "SILENT FAILURE"))  # fmt: skip
    except ValueError as e:
        rows.append(row("dependent patterns", "row3 = row1 + row2 (exactly)", "clear error",
                        str(e)[:70], "clear error"))  # fmt: skip
    run = periodic_run(sod, Protocol(n_periods=2))
    L = run.L.copy()
    L[2] = L[0] + L[1]
    import dataclasses

    try:
        estimate_frf(dataclasses.replace(run, L=L))
        rows.append(row("rank-deficient 𝓛", "measured L of exp. 3 = exp. 1 + exp. 2", "error",
                        "accepted", "SILENT FAILURE"))  # fmt: skip
    except ValueError as e:
        rows.append(row("rank-deficient 𝓛", "measured L of exp. 3 = exp. 1 + exp. 2",
                        "clear error", str(e)[:70], "clear error"))  # fmt: skip
    return rows


# ---------------------------------------------------------------------------------------
# 4. high noise
# ---------------------------------------------------------------------------------------


def _coverage(res, truth):
    """Fraction of model entries within 3 Laplace std of the truth, and the median
    |error|/std."""
    sd = res.model_std()
    z = []
    for a, b, s in zip(
        (res.model.hand.M, res.model.hand.B, res.model.hand.K,
         res.model.total.M, res.model.total.B, res.model.total.K),
        (truth.hand.M, truth.hand.B, truth.hand.K, truth.total.M, truth.total.B, truth.total.K),
        (sd.hand.M, sd.hand.B, sd.hand.K, sd.total.M, sd.total.B, sd.total.K),
        strict=True,
    ):  # fmt: skip
        z.append(
            np.abs(np.asarray(a) - np.asarray(b)).ravel()
            / np.maximum(np.asarray(s).ravel(), 1e-300)
        )
    z = np.concatenate(z)
    return float(np.mean(z <= 3.0)), float(np.median(z))


def case_noise(fast=False):
    n = 3
    truth = truth_model(n, seed=4)
    rows = []
    snrs = (20, 0) if fast else (40, 20, 10, 0)
    for snr in snrs:
        frf = model_frf(truth, PAPER_HZ, snr_db=snr, seed=5)
        ew = model_err(wls(frf), truth)
        res = fit_nls(frf, f_max_hz=None, weight="noise")
        en = model_err(res.model, truth)
        cov, med = _coverage(res, truth)
        rel_sd = float(
            np.median(np.asarray(res.std) / np.maximum(np.abs(np.asarray(res.theta)), 1e-12))
        )
        honest = cov >= 0.8
        rows.append(row(f"SNR {snr} dB", f"n={n}, paper grid, complex noise, noise weights",
                        "estimate with honest Laplace std (≥ 80 % of entries within 3σ)",
                        f"WLS err {ew:.2f}; NLS {res.status}, err {en:.2f}, median rel. std(θ) "
                        f"{rel_sd:.2f}, within 3σ {cov:.0%} (median |err|/σ {med:.1f}); boundary "
                        f"{res.boundary}", "right answer" if honest else "SILENT FAILURE"))  # fmt: skip
    # FRF estimation std at 0 dB force-sensor SNR
    sod = _sod(3, seed=4)
    prot = Protocol(n_periods=8, force_noise=0.3 if fast else 1.0, encoder_resolution=0.0)
    frf = estimate_frf(periodic_run(sod, prot))
    ZH, _ = sod.sampled_impedances(frf.omega)
    z = np.abs(np.asarray(frf.Z_H) - np.asarray(ZH)) / np.asarray(frf.Z_H_std)
    snr_meas = 20 * np.log10(np.median(np.abs(np.asarray(ZH))) / np.median(np.asarray(frf.Z_H_std)))
    ok = np.mean(z <= 3.0) > 0.9
    rows.append(row("FRF std at high noise", f"force noise {prot.force_noise} N/sample, 8 periods",
                    "element std covers the error (≥ 90 % within 3σ)",
                    f"Z_H element SNR ≈ {snr_meas:.0f} dB; within 3σ {np.mean(z <= 3):.0%}",
                    "right answer" if ok else "SILENT FAILURE"))  # fmt: skip
    return rows


# ---------------------------------------------------------------------------------------
# 5. stiff and near-singular M, B, K
# ---------------------------------------------------------------------------------------


def _sym_with_eigenvalues(rng, n: int):
    """``ev ↦ Q diag(ev) Qᵀ`` for one random orthogonal ``Q`` drawn from ``rng`` (symmetric
    matrices with prescribed eigenvalues sharing eigenvectors)."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return lambda ev: jnp.asarray((Q * np.asarray(ev, float)) @ Q.T)


def case_stiff(fast=False):
    rows = []
    n = 3
    sym = _sym_with_eigenvalues(np.random.default_rng(0), n)
    B, K = sym([20.0, 10.0, 5.0]), sym([1e3, 5e2, 2e2])
    for label, Mev in (("M ratio 1e6", [1.0, 1e-3, 1e-6]), ("M ratio 1e12", [1.0, 1e-6, 1e-12]),
                       ("M singular (rank 2)", [1.0, 0.5, 0.0])):  # fmt: skip
        so = SecondOrder(sym(Mev), B, K)
        r = np.asarray(so.roots())
        fin = r[np.isfinite(r)]
        ref = pencil_roots(so)
        ref_f = ref[np.isfinite(ref) & (np.abs(ref) < 1e9)]
        n_inf = int(np.sum(~np.isfinite(r)))
        e = match_roots(fin[np.abs(fin) < 1e9], ref_f) if len(ref_f) else 0.0
        nan = bool(np.any(np.isnan(r)))
        crhp = int(so.n_crhp_roots())
        ok = not nan and e < 1e-6 and np.all(np.real(fin) < 0)
        rows.append(row(f"stiff roots: {label}", "roots of M s²+Bs+K, B, K SPD",
                        "finite roots exact, roots at ∞ returned as inf (counted CRHP)",
                        f"finite roots err {e:.0e}, {n_inf} at ∞, NaN={nan}, n_crhp={crhp}",
                        "right answer" if ok else "SILENT FAILURE"))  # fmt: skip
    # WLS / positize / NLS on a stiff truth (hand M eigenvalues 1 … 1e-6)
    truth = truth_model(n, seed=6, m_hand=(1e-6, 1.0))
    frf = model_frf(truth, PAPER_HZ, snr_db=80, seed=7)
    m = wls(frf)
    mp = positize(m)
    rep, rep_p = crhp_report(m), crhp_report(mp)
    ref = [pencil_crhp(x) for x in (m.hand, m.total, mp.hand, mp.total)]
    got = [int(x) for x in (rep.hand, rep.total, rep_p.hand, rep_p.total)]
    lam = np.linalg.eigvalsh(np.asarray(truth.hand.M))
    lam_w = np.linalg.eigvalsh(0.5 * (np.asarray(m.hand.M) + np.asarray(m.hand.M).T))
    e_big = abs(lam_w[-1] - lam[-1]) / lam[-1]
    ok = e_big < 1e-2 and got == ref
    rows.append(row("stiff WLS + positize", "hand M eigenvalues 1e-6…1, SNR 80 dB, paper grid",
                    "largest M_H eigenvalue within 1 %; CRHP counts = scipy pencil counts",
                    f"M_H eig {lam_w[0]:.1e}/{lam_w[-1]:.3f} (true {lam[0]:.0e}/{lam[-1]:.3f}); "
                    f"CRHP hand/total {got[0]}/{got[1]}, after positize {got[2]}/{got[3]} "
                    f"(scipy {ref[0]}/{ref[1]}, {ref[2]}/{ref[3]})",
                    "right answer" if ok else "SILENT FAILURE"))  # fmt: skip
    res = fit_nls(frf, f_max_hz=None, max_steps=200 if fast else 500)
    lam_n = np.linalg.eigvalsh(np.asarray(res.model.hand.M))
    e_big = abs(lam_n[-1] - lam[-1]) / lam[-1]
    # the largest hand-mass eigenvalue is identifiable whatever the status: a fit that misses
    # it is wrong, converged or not; the tiny one is not (so no whole-model error bound here)
    ok = e_big < 1e-2
    rows.append(row("stiff NLS", "same data, fit_nls(f_max_hz=None)",
                    "largest M_H eigenvalue within 1 % (converged, or max_steps + boundary flag)",
                    f"{res.status} in {int(res.n_steps)} steps; M_H eig {lam_n[0]:.1e}/"
                    f"{lam_n[-1]:.3f} (err {e_big:.1e}); boundary {res.boundary}; CRHP "
                    f"{int(crhp_report(res.model).hand)}",
                    ("right answer" if res.ok else "clear warning") if ok else "SILENT FAILURE"))  # fmt: skip
    # PD parameterization with an exactly zero M block
    p = n_params(n)
    t = n * (n + 1) // 2
    theta = jnp.asarray(np.random.default_rng(1).standard_normal(p)).at[:t].set(0.0)  # M_H = 0
    mz = theta_to_model(theta)
    r = np.asarray(mz.hand.roots())
    rows.append(row("PD model with M_H = 0", "theta_to_model with the M_H block zero",
                    "first-order hand: n finite OLHP roots, n at ∞ (no NaN)",
                    f"{int(np.sum(np.isfinite(r)))} finite (max Re {np.max(np.real(r[np.isfinite(r)])):.2g}), "
                    f"{int(np.sum(np.isinf(r)))} at ∞, NaN={bool(np.any(np.isnan(r)))}",
                    "right answer" if not np.any(np.isnan(r)) else "SILENT FAILURE"))  # fmt: skip
    return rows


# ---------------------------------------------------------------------------------------
# 6. large n, many frequencies
# ---------------------------------------------------------------------------------------


def _random_stable_ss(rng, n, nx):
    A = rng.standard_normal((nx, nx))
    A = A - (np.max(np.real(np.linalg.eigvals(A))) + rng.uniform(0.5, 2.0)) * np.eye(nx)
    return StateSpace(jnp.asarray(A), jnp.asarray(rng.standard_normal((nx, n))),
                      jnp.asarray(rng.standard_normal((n, nx))), jnp.zeros((n, n)))  # fmt: skip


def case_large_n(fast=False):
    rows = []
    n = 6 if fast else 12
    N = 200 if fast else 2000
    truth = truth_model(n, seed=8)
    f = np.geomspace(0.5, 500.0, N)
    frf = model_frf(truth, f)
    t0 = time.perf_counter()
    m = wls(frf)
    jax.block_until_ready(m)
    dt = time.perf_counter() - t0
    e = model_err(m, truth)
    rows.append(row("large n: WLS", f"n={n}, {N} freqs 0.5–500 Hz, noise-free",
                    "exact (rounding)", f"err {e:.1e}, {dt:.2f} s (incl. compile)",
                    "right answer" if e < 1e-8 else "SILENT FAILURE"))  # fmt: skip
    # NLS with the P residual: its dense Jacobian at N = 2000 would be GBs: hapid warns up
    # front (without P the residual is compressed to 6 rows per element: no GB arrays)
    _, msgs = caught(lambda: hapid.fit._nls._warn_jacobian_size(frf, True))
    big = 8.0 * 6 * n * n * N * n_params(n) / 1e9
    rows.append(row("large n: NLS size", f"fit_nls(use_P_residual=True) on n={n}, {N} freqs",
                    "warn before a multi-GB Jacobian, not below 1 GB",
                    f"J {big:.2f} GB; warned={bool(msgs)}",
                    ("clear warning" if msgs else "SILENT FAILURE") if big > 1 else
                    ("right answer" if not msgs else "clear warning"),
                    ok=bool(msgs) == (big > 1)))  # fmt: skip
    Nn = 30 if fast else 100
    sub = model_frf(truth, np.geomspace(0.5, 100.0, Nn), snr_db=60, seed=9)
    t0 = time.perf_counter()
    res = fit_nls(sub, f_max_hz=None, max_steps=100 if fast else 300)
    dt = time.perf_counter() - t0
    e = model_err(res.model, truth)
    rows.append(row("large n: NLS", f"n={n} ({n_params(n)} params), {Nn} freqs, SNR 60 dB",
                    "converged or honest status", f"{res.status} in {int(res.n_steps)} steps, "
                    f"err {e:.1e}, {dt:.0f} s", nls_outcome(res, e, 0.05, truth)[0]))  # fmt: skip
    # generalized Nyquist at n = 12 / 2000 frequencies against closed-loop poles
    rng = np.random.default_rng(3)
    agree, cases = 0, 0
    w = np.logspace(-3, 4, N)
    t0 = time.perf_counter()
    for _k in range(2 if fast else 6):
        P = _random_stable_ss(rng, n, 2 * n)
        c = 10 ** rng.uniform(-1.5, 1.0)
        G = StateSpace(-10.0 * jnp.eye(n), 10.0 * c * jnp.eye(n), jnp.eye(n), jnp.zeros((n, n)))
        cl = np.asarray(closed_loop_poles(P, G))
        if np.any(np.abs(cl.real) < 0.01 * np.abs(cl)):
            continue
        r = analyze_loop(P.at_omega(w), G.at_omega(w), jnp.asarray(w))
        cases += 1
        agree += int(bool(r.stable) == bool(np.all(cl.real < 0)) and bool(r.nyquist_resolved))
    dt = time.perf_counter() - t0
    rows.append(row("large n: Nyquist", f"n={n}, {N} freqs, random stable plants, low-pass gain",
                    "verdict = closed-loop poles", f"{agree}/{cases} agree, {dt:.1f} s",
                    "right answer" if agree == cases else "SILENT FAILURE"))  # fmt: skip
    return rows


# ---------------------------------------------------------------------------------------
# 7. nearly non-minimum-phase models and positizing
# ---------------------------------------------------------------------------------------


def case_positize(fast=False):
    rows = []
    n = 3
    rng = np.random.default_rng(10)
    sym = _sym_with_eigenvalues(rng, n)
    M, K = sym([1.0, 0.5, 0.2]), sym([1e3, 500.0, 200.0])
    for label, b0 in (("B eigenvalue +1e-9 (roots Re ≈ −5e-10)", 1e-9),
                      ("B eigenvalue −1e-9 (roots Re ≈ +5e-10)", -1e-9)):  # fmt: skip
        so = SecondOrder(M, sym([20.0, 10.0, b0]), K)
        model = ImpedanceModel(so, so)
        rep = crhp_report(model)
        rep_tol = crhp_report(model, tol=1e-6)
        pos = crhp_report(positize(model))
        true_crhp = int(np.sum(np.real(pencil_roots(so)) >= 0))
        ok = int(rep.hand) == true_crhp and int(rep_tol.hand) == 2 and bool(pos.ok)
        rows.append(row("nearly NMP: " + label, "M, K SPD; one lightly damped direction",
                        "CRHP count exact at tol=0; tol=1e-6 flags the near-axis pair",
                        f"n_crhp tol=0: {int(rep.hand)} (true {true_crhp}), tol=1e-6: "
                        f"{int(rep_tol.hand)}; after positize: {int(pos.hand)}",
                        "right answer" if ok else "SILENT FAILURE"))  # fmt: skip
    # random non-symmetric WLS-like models: positize is "usually (but not always)" enough
    trials = 50 if fast else 400
    fails = mismatch = nan = 0
    for _ in range(trials):
        mk = lambda s: jnp.asarray(s * (np.eye(n) + 0.6 * rng.standard_normal((n, n))))  # noqa: E731
        so = SecondOrder(mk(1.0), mk(20.0), mk(1e3))
        pm = positize(ImpedanceModel(so, so))
        nan += int(np.any(np.isnan(np.asarray(pm.hand.roots()))))
        bad = pencil_crhp(pm.hand)  # reference: scipy's generalized eigenvalues
        rep = int(crhp_report(pm).hand)
        fails += int(bad > 0)
        mismatch += int(rep != bad)
    rows.append(row("positize on random non-symmetric models",
                    f"{trials} models M, B, K = c(I + 0.6·randn)", "CRHP roots left by positize "
                    "(scipy pencil count) are reported by crhp_report", f"{fails}/{trials} keep CRHP roots after "
                    f"positize; crhp_report ≠ scipy count in {mismatch}; NaN roots {nan}",
                    "clear warning" if mismatch == 0 and not nan else "SILENT FAILURE"))  # fmt: skip
    return rows


# ---------------------------------------------------------------------------------------
# 8. loci close to −1
# ---------------------------------------------------------------------------------------


def _third_order(a):
    """SISO l(s) = a/((s+1)(s/10+1)(s/100+1)) as a state space (companion form)."""
    p = np.poly([-1.0, -10.0, -100.0])  # s³ + 111 s² + 1110 s + 1000
    k = a * 1000.0
    A = np.array([[0, 1, 0], [0, 0, 1], [-p[3], -p[2], -p[1]]], float)
    return A, np.array([[0.0], [0.0], [1.0]]), np.array([[k, 0.0, 0.0]]), np.zeros((1, 1))


def case_near_minus_one(fast=False):
    rows = []
    N = 600 if fast else 3000
    w = np.logspace(-2, 4, N)
    # phase crossover of l(s)/a: ω₁₈₀ = √(1110) (closed form for this polynomial)
    w180 = np.sqrt(1110.0)
    l1 = 1000.0 / np.abs((1j * w180 + 1) * (1j * w180 + 10) * (1j * w180 + 100))
    n = 2
    R = np.array([[1.0, 0.3], [-0.2, 1.0]])
    for delta in (1e-1, 1e-2, 1e-6, 0.0, -1e-6):
        a = (1 - delta) / l1  # the locus passes through −1 + δ
        A1, B1, C1, D1 = _third_order(a)
        # MIMO: two copies mixed by R (same loci), so the loop is genuinely 2×2
        A = np.kron(np.eye(n), A1)
        Bm = np.kron(np.eye(n), B1) @ np.linalg.inv(R)
        C = R @ np.kron(np.eye(n), C1)
        P = StateSpace(jnp.asarray(A), jnp.asarray(Bm), jnp.asarray(C), jnp.zeros((n, n)))
        G = StateSpace(jnp.zeros((0, 0)), jnp.zeros((0, n)), jnp.zeros((n, 0)), jnp.eye(n))
        cl = np.asarray(closed_loop_poles(P, G))
        truth = (
            "stable"
            if np.all(cl.real < -1e-9)
            else ("marginal" if np.all(cl.real < 1e-9) else "unstable")
        )
        r = analyze_loop(
            P.at_omega(w), jnp.broadcast_to(jnp.eye(n), (N, n, n)).astype(complex), jnp.asarray(w)
        )
        st, res, sing = bool(r.stable), bool(r.nyquist_resolved), bool(r.singular)
        nan_verdict = not np.isfinite(float(r.n_encirclements))
        right = st if truth == "stable" else not st  # marginal: must not be called stable
        warned = not st and not res  # unresolved grid → not called stable (conservative)
        outcome = "right answer" if right else ("clear warning" if warned else "SILENT FAILURE")
        if nan_verdict:
            outcome = "SILENT FAILURE"
        bw = float(r.iso_bandwidth_hz)
        rows.append(row(f"locus through −1{'+' if delta >= 0 else ''}{delta:g}",
                        f"2×2 loop, {N} freqs; closed loop {truth}",
                        "= closed-loop poles, or unresolved → not stable; marginal → not stable",
                        f"stable={st} resolved={res} singular={sing} N_enc="
                        f"{float(r.n_encirclements):g}; GM {float(r.gm_db):.2g} dB; bw "
                        f"{'NaN' if np.isnan(bw) else f'{bw:.3g} Hz'}",
                        outcome))  # fmt: skip
    # the locus hits −1 exactly at a grid frequency: singular I + PG
    w2 = np.logspace(-1, 2, 301)
    s = 1j * w2
    P = (w2[150] ** 2 / s**2)[:, None, None] * np.eye(2)
    r = analyze_loop(P, np.broadcast_to(np.eye(2), P.shape), w2)
    ok = bool(r.singular) and not bool(r.stable) and np.isnan(float(r.iso_bandwidth_hz))
    rows.append(row("singular I + PG", "L(jω₀) = −I exactly at a grid point",
                    "singular flagged, not stable, performance NaN",
                    f"singular={bool(r.singular)} at {float(r.singular_hz):.3g} Hz, "
                    f"stable={bool(r.stable)}", "clear warning" if ok else "SILENT FAILURE"))  # fmt: skip
    # a grid too coarse to resolve det(I + L)'s phase
    wc = np.logspace(-2, 4, 12)
    A1, B1, C1, D1 = _third_order(0.5 / l1)
    Pc = C1 @ np.linalg.solve(
        1j * wc[:, None, None] * np.eye(3) - A1, np.broadcast_to(B1, (12, 3, 1))
    )
    r = analyze_loop(jnp.asarray(Pc), jnp.ones((12, 1, 1), complex), jnp.asarray(wc))
    ok = not bool(r.nyquist_resolved) and not bool(r.stable)
    rows.append(row("coarse grid", "12 points over 6 decades, stable SISO loop (GM 6 dB)",
                    "not resolved → not called stable", f"resolved={bool(r.nyquist_resolved)}, "
                    f"stable={bool(r.stable)}", "clear warning" if ok else
                    ("right answer" if bool(r.stable) else "SILENT FAILURE")))  # fmt: skip
    # NaN in P (e.g. a singular model response at one grid point)
    Pn = np.asarray(P).copy()
    Pn[10] = np.nan
    r = analyze_loop(
        jnp.asarray(Pn), jnp.broadcast_to(jnp.eye(2), Pn.shape).astype(complex), jnp.asarray(w2)
    )
    ok = not bool(r.stable) and not bool(r.nyquist_resolved)
    rows.append(row("NaN in P", "one grid point of P is NaN", "not stable, unresolved (no NaN "
                    "verdict)", f"stable={bool(r.stable)}, resolved={bool(r.nyquist_resolved)}",
                    "clear warning" if ok else "SILENT FAILURE"))  # fmt: skip
    return rows


CASES = [
    case_float32_input,
    case_float32_arith,
    case_x64_off,
    case_wide_grid,
    case_excitation,
    case_noise,
    case_stiff,
    case_large_n,
    case_positize,
    case_near_minus_one,
]
