"""Issue 13 study: can an EXACT screen spare the eigenvalues of L at (almost) every frequency?

Run: ``.venv/bin/python benchmarks/study_loci_screen.py [--quick]`` (standalone; not a
``run_all.py`` section: it measures a design question, not a goal).

``loop_metrics`` needs the eigenvalues of ``L(jω)`` (characteristic loci) on every grid
interval because the reference rules read them there: the resolution of every paired locus
``1 + λᵢ`` (phase step < π/2) and the margin candidates (a paired locus crossing the unit
circle, or the negative real axis). A screen may skip an interval only if it *proves* that
no pairing the reference could choose gives an unresolved step or a candidate there. On cu5
posterior draws (paper design, the robust check's loops) this script measures:

1. **What the reference finds** (LAPACK ``eigvals`` + the optimal pairing): how many
   intervals carry a candidate at all, and the magnitude of the loci that make them. Few
   intervals do (≈ 8 of 999) — a screen would pay *if* it could prove the others empty.
2. **A sound per-interval screen** — Gershgorin discs of ``V⁻¹ L(jω) V`` in the eigenbasis
   ``V`` of a nearby anchor frequency (anchors every ``s`` points; eigenvectors by inverse
   iteration), discs inflated for rounding, pairing-free tests on every disc pair
   (resolution ``|b − a| < |1 + a|``, both discs on one side of the real axis / of
   ``Re = 0``, both inside / outside the unit circle) plus the disjoint-disc argument
   that excludes pairs the optimal permutation cannot choose. Share of intervals it cannot
   decide, by reason, and its cost against the eigenvalue kernel it would spare.
3. **The characteristic-polynomial route** (the counts of roots inside the unit circle /
   in the upper half plane need accurate coefficients): Faddeev–LeVerrier and Hessenberg +
   La Budde coefficients against ``np.poly(eigvals)`` — how accurately the roots of the
   computed polynomial reproduce each locus, in particular the tiny loci
   (``|λ| ≈ 1e-10 … 1e-7`` against ``‖L‖ ≈ 1``) whose negative-real-axis crossings the
   reference counts — and the cost of the coefficients alone in XLA (batch last).
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Section, fs, measure, standalone, table  # noqa: E402

import hapid  # noqa: E402,F401
from hapid.control import _kernels as K  # noqa: E402

_EPS = float(np.finfo(np.float64).eps)


def _loops(S: int, N: int):
    from hapid.control import Compensator, inverse_model_response
    from hapid.device import cu5
    from hapid.experiment import Protocol, estimate_frf, periodic_run
    from hapid.fit import fit_nls
    from hapid.uncertainty import laplace_samples, posterior_omega

    nls = fit_nls(estimate_frf(periodic_run(cu5(), Protocol(), noise_seed=0)))
    w = jnp.asarray(posterior_omega(N))
    G = inverse_model_response(nls.model, Compensator.paper(), w)
    models = laplace_samples(nls, S, key=5).models(np.arange(S))
    Ps = jax.jit(jax.vmap(lambda m: m.P(1j * w)))(models)
    return np.asarray(jnp.einsum("swij,wjk->swik", Ps, G))


# --------------------------------------------------------------------------------------
# 1. the reference's candidates


def _reference_candidates(L):
    from hapid.control._margins import gain_crossing, phase_crossing

    e = np.linalg.eigvals(L).T  # (n, N)
    a = jnp.asarray(e[:, :-1])
    b = K.pair_optimal(a, jnp.asarray(e[:, 1:]))
    okg = np.asarray(phase_crossing(a, b)[0])
    okp = np.asarray(gain_crossing(a, b)[0])
    nrm = np.linalg.norm(L, axis=(1, 2))[None, :-1]
    tiny = okg & (np.abs(np.asarray(a)) < 1e-6 * nrm)
    # an ideal count screen (counts read off the exact eigenvalues): intervals where the
    # number of loci with Im λ ≥ 0 (resp. |λ| < 1) does not change, yet a locus crosses
    up = np.sum(np.imag(e) >= 0, axis=0)
    ins = np.sum(np.abs(e) < 1, axis=0)
    miss_g = okg.any(0) & (np.diff(up) == 0)
    miss_p = okp.any(0) & (np.diff(ins) == 0)
    # the resolution rule has a pairing-free proof only where every |λ| < 1/3 at both ends
    rho = np.max(np.abs(e), axis=0)
    no_proof = np.maximum(rho[:-1], rho[1:]) >= 1.0 / 3.0
    return {
        "any": int((okg | okp).any(0).sum()),
        "phase": int(okg.any(0).sum()),
        "phase_tiny": int(tiny.any(0).sum()),
        "gain": int(okp.any(0).sum()),
        "miss": int((miss_g | miss_p).sum()),
        "no_proof": int(no_proof.sum()),
    }


# --------------------------------------------------------------------------------------
# 2. a sound screen: Gershgorin discs in a nearby anchor's eigenbasis


def _eigvecs(Le, lam):
    """Eigenvectors (columns, ``(n, n, B)``) of ``Le (n, n, B)`` for eigenvalues ``lam (n, B)``
    by two steps of inverse iteration (shift 1e-10·‖A‖ off the eigenvalue)."""
    n = Le.shape[0]
    eye = jnp.eye(n)[:, :, None]
    f = jnp.sqrt(K.fro2(Le))
    cols = []
    for i in range(n):
        mu = lam[i] + 1e-10 * (f + 1e-300) * (1 + 1j) / np.sqrt(2)
        _, Ai = K.det_inv(Le - eye * mu, unroll=True)
        x = jnp.sum(Ai, axis=1)
        for _ in range(2):
            x = x / jnp.sqrt(jnp.sum(jnp.abs(x) ** 2, axis=0))
            x = jnp.einsum("ik...,k...->i...", Ai, x)
        cols.append(x / jnp.sqrt(jnp.sum(jnp.abs(x) ** 2, axis=0)))
    return jnp.stack(cols, axis=1)


def gershgorin_screen(L, s: int, step=np.pi / 2):
    """Per interval: True where the screen proves that no pairing the reference can choose
    gives an unresolved step or a margin candidate (module docstring, 2.); also the
    undecided counts per reason (resolution, negative-real-axis, unit-circle)."""
    N, n, _ = L.shape
    Le = K.to_entries(L)
    anc = jnp.arange(0, N, s)
    La = Le[:, :, anc]
    V = _eigvecs(La, K.eigvals(La))
    _, Vi = K.det_inv(V, unroll=True)
    blk = jnp.arange(N - 1) // s
    fL = jnp.sqrt(K.fro2(Le))
    kap = jnp.sqrt(K.fro2(V) * K.fro2(Vi))

    def discs(j):
        M = K.matmul(K.matmul(Vi[:, :, blk], Le[:, :, j]), V[:, :, blk])
        eta = 64 * n * _EPS * kap[blk] * fL[j]  # rounding of M and of computed eigenvalues
        c = jnp.stack([M[i, i] for i in range(n)])
        r = jnp.stack([sum(jnp.abs(M[i, k]) for k in range(n) if k != i) for i in range(n)])
        return c, r + eta

    j = jnp.arange(N - 1)
    ca, ra = discs(j)
    cb, rb = discs(j + 1)
    A, B = (lambda x: x[:, None]), (lambda x: x[None, :])
    d = jnp.abs(B(cb) - A(ca))
    up = d + A(ra) + B(rb)
    lo = jnp.maximum(d - A(ra) - B(rb), 0.0)
    res = up < np.sin(min(step, np.pi / 2)) * (jnp.abs(1 + A(ca)) - A(ra))
    ia, ib, qa, qb = jnp.imag(A(ca)), jnp.imag(B(cb)), jnp.real(A(ca)), jnp.real(B(cb))
    ra2, rb2 = A(ra), B(rb)
    noph = (
        ((ia - ra2 > 0) & (ib - rb2 > 0))
        | ((ia + ra2 < 0) & (ib + rb2 < 0))
        | ((qa - ra2 > 0) & (qb - rb2 > 0))
    )
    ma, mb = jnp.abs(A(ca)), jnp.abs(B(cb))
    nogn = ((ma + ra2 < 1) & (mb + rb2 < 1)) | ((ma - ra2 > 1) & (mb - rb2 > 1))

    def disjoint(c, r):
        ok = jnp.ones(c.shape[1:], bool)
        for i in range(n):
            for k in range(i + 1, n):
                ok &= jnp.abs(c[i] - c[k]) > r[i] + r[k]
        return ok

    dis = disjoint(ca, ra) & disjoint(cb, rb)
    U = sum(up[i, i] ** 2 for i in range(n))
    excl = dis[None, None] & ~jnp.eye(n, dtype=bool)[:, :, None] & (lo**2 > U[None, None])
    skip = jnp.all((res & noph & nogn) | excl, axis=(0, 1))
    why = [~jnp.all(x | excl, axis=(0, 1)) for x in (res, noph, nogn)]
    return skip, jnp.stack([jnp.sum(x) for x in why])


# --------------------------------------------------------------------------------------
# 3. the characteristic polynomial


def faddeev_np(A):
    """Coefficients (highest first) of det(λI − A), Faddeev–LeVerrier (numpy)."""
    n = A.shape[0]
    c, M, eye = [1.0 + 0j], np.zeros_like(A), np.eye(n)
    for k in range(1, n + 1):
        M = A @ M + c[-1] * eye
        c.append(-np.trace(A @ M) / k)
    return np.array(c)


def _labudde_lists(H):
    """La Budde's recursion on Hessenberg entry lists: coefficient lists (highest first)."""
    n = len(H)
    one = jnp.ones_like(H[0][0])
    p = [[one]]
    for k in range(n):
        a = p[k] + [0.0 * one]
        a = [a[m] - (H[k][k] * p[k][m - 1] if m >= 1 else 0.0) for m in range(k + 2)]
        prod = one
        for i in range(k - 1, -1, -1):
            prod = prod * H[i + 1][i]
            off = k + 2 - len(p[i])
            a = [a[m] - (H[i][k] * prod * p[i][m - off] if m >= off else 0.0) for m in range(k + 2)]
        p.append(a)
    return p[n]


def labudde(A):
    """Coefficients ``(n + 1, ...)`` (highest first) of det(λI − A) for ``A (n, n, ...)``:
    Householder to Hessenberg (:func:`hapid.control._kernels.hessenberg`), La Budde."""
    return jnp.stack(_labudde_lists(K.hessenberg(A)))


def _poly_accuracy(L, ks):
    """Relative error of every locus as a root (``np.roots``) of the computed polynomial."""
    rows = []
    lab = np.asarray(labudde(K.to_entries(jnp.asarray(L[ks]))))  # (n + 1, K)
    for col, k in enumerate(ks):
        e = np.linalg.eigvals(L[k])
        e = e[np.argsort(np.abs(e))]
        ref = np.poly(e)
        for name, c in (
            ("Faddeev–LeVerrier", faddeev_np(L[k])),
            ("Hessenberg + La Budde", lab[:, col]),
        ):
            r = np.roots(c)
            err = [np.min(np.abs(r - x)) / abs(x) for x in e]
            cerr = np.abs(c[-1] - ref[-1]) / np.abs(ref[-1])
            rows.append({"ω index": k, "coefficients": name,
                         "|λ| (smallest → largest)": " ".join(f"{abs(x):.1e}" for x in e),
                         "relative error of each locus (np.roots of the coefficients)": " ".join(f"{x:.0e}" for x in err),
                         "rel. error of det L vs np.poly(eigvals)": f"{cerr:.0e}"})  # fmt: skip
    return rows


def trace_disc_screen(L):
    """The cheapest sound enclosure: every eigenvalue of ``L (N, n, n)`` lies in the disc
    ``|λ − c| ≤ r``, ``c = tr L/n``, ``r = ‖L − cI‖_F`` (Schur), inflated for rounding; an
    interval's two discs lie in one disc of centre ``m`` and radius ``R``. Undecided, each
    ``(N − 1,)`` bool: the disc meets the unit circle, meets the negative real axis, or sees
    ``−1`` under a half-angle ≥ π/4 (two points of it may differ in phase by ≥ π/2 about −1)."""
    n = L.shape[-1]
    c = np.trace(L, axis1=-2, axis2=-1) / n
    r = np.linalg.norm(L - c[:, None, None] * np.eye(n), axis=(-2, -1)) * (1 + 1e-8)
    m = 0.5 * (c[1:] + c[:-1])
    R = 0.5 * np.abs(c[1:] - c[:-1]) + np.maximum(r[1:], r[:-1])
    circle = (np.abs(m) - R <= 1) & (np.abs(m) + R >= 1)
    axis = (np.abs(m.imag) <= R) & (m.real - R < 0)
    res = R >= np.abs(1 + m) * np.sin(np.pi / 4)
    return res, axis, circle


def _one_grid(sec: Section, S: int, N: int) -> None:
    """Sections 1 and 2 (and the coefficients' cost) for ``S`` draws on ``N`` frequencies."""
    Ls = _loops(S, N)
    cand = [_reference_candidates(L) for L in Ls]
    med = {k: float(np.median([c[k] for c in cand])) for k in cand[0]}
    mx = {k: int(np.max([c[k] for c in cand])) for k in cand[0]}
    rows = [{"intervals": f"{N - 1}", "with any candidate (median / max)": f"{med['any']:g} / {mx['any']}",
             "negative-real-axis candidates": f"{med['phase']:g} / {mx['phase']}",
             "… by a locus |λ| < 1e-6‖L‖": f"{med['phase_tiny']:g} / {mx['phase_tiny']}",
             "unit-circle candidates": f"{med['gain']:g} / {mx['gain']}",
             "missed by an ideal count screen (opposite crossings cancel)": f"{med['miss']:g} / {mx['miss']}",
             "resolution rule without a pairing-free proof (ρ(L) ≥ 1/3)": f"{med['no_proof']:g} / {mx['no_proof']}"}]  # fmt: skip
    sec.add(f"### 1. The reference's candidates, {S} cu5 draws, N = {N}\n\n" + table(rows))
    Le = K.to_entries(jnp.asarray(Ls[0]))
    eig = jax.jit(K.eigvals)
    pair = jax.jit(K.pair_optimal)
    e = eig(Le)
    _, _, t_eig = measure(lambda: eig(Le), repeat=5)
    _, _, t_pair = measure(lambda: pair(e[:, :-1], e[:, 1:]), repeat=5)
    # one output that reads every coefficient (as a root count would): XLA fuses the
    # unrolled reduction and recursion into one loop (a stacked multi-output version is
    # duplicated into every output's fusion and measured 5-10x the QR eigenvalues' time)
    lab = jax.jit(lambda A: sum(jnp.abs(c) for c in _labudde_lists(K.hessenberg(A))))
    _, _, t_lab = measure(lambda: lab(Le), repeat=5)
    rows = []
    for s in (2, 8):
        scr = jax.jit(lambda L, s=s: gershgorin_screen(L, s))
        und, why = [], []
        for L in Ls:
            skip, w_ = scr(jnp.asarray(L))
            und.append(int(np.sum(~np.asarray(skip))))
            why.append(np.asarray(w_))
        _, _, t_scr = measure(lambda scr=scr: scr(jnp.asarray(Ls[0])), repeat=5)
        why = np.median(np.array(why), axis=0)
        rows.append({"anchors every": f"{s} points", "undecided intervals (median / min)":
                     f"{np.median(und):g} / {np.min(und)} of {N - 1}",
                     "… resolution / −1-axis / unit circle (median)": " / ".join(f"{x:g}" for x in why),
                     "screen cost": fs(t_scr), "eigenvalues it would spare (XLA QR)": fs(t_eig),
                     "+ pairing": fs(t_pair)})  # fmt: skip
    sec.add(f"### 2. Gershgorin discs in an anchor's eigenbasis (sound screen), N = {N}\n\n"
            + table(rows))  # fmt: skip
    td = np.array([[np.mean(x) for x in trace_disc_screen(L)] for L in Ls])  # (S, 3)
    anyu = [np.mean(np.logical_or.reduce(trace_disc_screen(L))) for L in Ls]
    spread = np.median(
        [
            np.median(
                np.linalg.norm(L, axis=(-2, -1))
                / np.maximum(np.abs(np.trace(L, axis1=-2, axis2=-1)) / L.shape[-1], 1e-300)
            )
            for L in Ls
        ]
    )
    sec.add(f"Trace discs (centre tr L/n, radius ‖L − tr L/n·I‖_F: the cheapest sound "
            f"enclosure of every eigenvalue), N = {N}: undecided intervals (mean over draws) "
            f"resolution {100 * np.mean(td[:, 0]):.0f} %, negative real axis "
            f"{100 * np.mean(td[:, 1]):.0f} %, unit circle {100 * np.mean(td[:, 2]):.0f} %, any "
            f"{100 * np.mean(anyu):.0f} % — the loci are not clustered about their mean "
            f"(median ‖L‖_F / |tr L/n| = {spread:.1f}: one large locus and n − 1 small ones).")  # fmt: skip
    sec.add(f"Characteristic-polynomial coefficients alone (Hessenberg + La Budde, XLA, batch "
            f"last, one fused output), N = {N}: {fs(t_lab)} against {fs(t_eig)} for all "
            "eigenvalues (XLA QR) — before any root count (Schur–Cohn, Routh–Hurwitz: O(n²) "
            "per frequency). Cheap enough to pay, if the counts could decide the rules "
            "(section 1: they cannot).")  # fmt: skip


def run(quick: bool = False, out: str = "out/bench") -> Section:
    sec = Section("Issue 13 study: an exact screen for the eigenvalues of L")
    S = 5 if quick else 20
    for N in (1000,) if quick else (1000, 3000):
        _one_grid(sec, S, N)
    L0 = _loops(1, 1000)[0]
    sec.add("### 3. Accuracy of the characteristic polynomial (one cu5 draw, N = 1000)\n\n"
            + table(_poly_accuracy(L0, [0, 300, 450, 700, 900])))  # fmt: skip
    return sec


def main(argv=None):
    return standalone(run, __doc__, argv)


if __name__ == "__main__":
    main()
