"""Eigenvalues of L at every frequency and the pairing of loci: the XLA kernels of
:mod:`hapid.control._kernels` against LAPACK and against the alternatives measured for
issue 13 (goal: ≤ 0.6 µs per complex 5 × 5 matrix, pairing ≤ 0.15 µs per pair).

Run: ``PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_eig.py [--quick]`` (``--quick``:
no cu5 loops, fewer repeats). Prints one markdown table per part:

1. µs per matrix at B = 1000 and 3000: the kernel in use (``K.eigvals``: Householder →
   Hessenberg, Wilkinson-shifted QR, one ``while_loop`` per deflation stage), LAPACK
   (``jnp.linalg.eigvals``) and two alternatives kept here for the record:
   ``window QR`` (one implicit single-shift sweep per step over every matrix's own active
   window, all deflation stages in one loop) and ``charpoly+Aberth`` (characteristic
   polynomial of ``(A − cI)/s`` by traces of powers and Newton's identities, 12 Gauss–Seidel
   Aberth–Ehrlich iterations from a circle).
2. Max error vs numpy's LAPACK per test family, as ``max |λ − λ_ref| / (1e-12‖A‖_F +
   1e-10|λ_ref|)`` over the optimal matching (≤ 1: within the tolerance of
   tests/test_kernels_eig.py).
3. Pairing (``pair_optimal``): the previous select-chain DP against the level-reduced DP.
4. Compile times: ``jax.jit(K.eigvals)`` at n = 5 and ``loop_metrics`` on a 5 × 5 loop
   (first call minus warm call).
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import hapid  # noqa: F401  (float64)
from hapid.control import _kernels as K

# the previous pairing (select-chain DP), for comparison: the tests' reference of the tie rule
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from test_kernels_eig import _pair_select_chain as pair_select_chain  # noqa: E402

_ULP = float(np.finfo(np.float64).eps)
_SAFMIN = float(np.finfo(np.float64).tiny)


# --- alternative 1: one QR loop for all deflation stages (per-matrix active window) ---------


def _cabs1(z):
    return jnp.abs(jnp.real(z)) + jnp.abs(jnp.imag(z))


def _abs2(z):
    return jnp.real(z) ** 2 + jnp.imag(z) ** 2


def _givens(a, b):
    aa = _abs2(a)
    ra = jnp.sqrt(aa)
    r = jnp.sqrt(aa + _abs2(b))
    ok, a_ok = r > 0, ra > 0
    t = 1.0 / jnp.where(a_ok, ra * r, jnp.where(ok, r, 1.0))
    c = jnp.where(a_ok, aa * t, jnp.where(ok, 0.0, 1.0))
    s = jnp.where(a_ok, a, 1.0) * jnp.conj(b) * t
    return c, s


def _deflate(H):
    for k in range(len(H) - 1):
        sub = _cabs1(H[k + 1][k])
        tst = _cabs1(H[k][k]) + _cabs1(H[k + 1][k + 1])
        small = (sub <= _ULP * tst) | (sub <= _SAFMIN) | ~jnp.isfinite(sub)
        H[k + 1][k] = jnp.where(small, 0.0, H[k + 1][k])
    return H


def _window(H):
    n = len(H)
    nz = [None] + [H[k][k - 1] != 0 for k in range(1, n)]
    e = jnp.zeros(jnp.shape(H[0][0]), dtype=jnp.int32)
    for k in range(1, n):
        e = jnp.where(nz[k], k, e)
    l = jnp.zeros_like(e)
    for k in range(1, n - 1):
        l = jnp.where(~nz[k] & (k < e), k, l)
    return l, e


def _window_step(H, exceptional):
    n = len(H)
    H = [row[:] for row in H]
    l, e = _window(H)

    def at(i, j):
        out = H[1 + i][1 + j]
        for m in range(2, n):
            out = jnp.where(e == m, H[m + i][m + j], out)
        return out

    h11, h12, h21, h22 = at(-1, -1), at(-1, 0), at(0, -1), at(0, 0)
    t = 0.5 * (h11 - h22)
    disc = jnp.sqrt(t * t + h12 * h21)
    mu = h22 + jnp.where(_cabs1(t + disc) <= _cabs1(t - disc), t + disc, t - disc)
    mu = jnp.where(exceptional, h22 + 0.75 * jnp.abs(jnp.real(h21)), mu)
    bulge = None
    for k in range(n - 1):
        a = H[0][0] - mu if k == 0 else jnp.where(l == k, H[k][k] - mu, H[k][k - 1])
        b = H[1][0] if k == 0 else jnp.where(l == k, H[k + 1][k], bulge)
        act = (l <= k) & (k < e)
        c, s = _givens(a, b)
        c, s = jnp.where(act, c, 1.0), jnp.where(act, s, 0.0)
        sc = jnp.conj(s)
        if k > 0:
            H[k][k - 1] = c * H[k][k - 1] + s * bulge
        for j in range(k, n):
            x, y = H[k][j], H[k + 1][j]
            H[k][j], H[k + 1][j] = c * x + s * y, c * y - sc * x
        for i in range(min(k + 2, n)):
            x, y = H[i][k], H[i][k + 1]
            H[i][k], H[i][k + 1] = c * x + sc * y, c * y - s * x
        if k + 2 < n:
            y = H[k + 2][k + 1]
            bulge, H[k + 2][k + 1] = sc * y, c * y
    return H


def window_qr_eigvals(A, max_iter: int = 200):
    n = A.shape[0]
    H = _deflate(K.hessenberg(jnp.asarray(A, jnp.complex128)))
    idx = [(i, j) for i in range(n) for j in range(max(i - 1, 0), n)]

    def unflat(f):
        H = [[jnp.zeros_like(f[0]) for _ in range(n)] for _ in range(n)]
        for q, (i, j) in enumerate(idx):
            H[i][j] = f[q]
        return H

    def cond(c):
        return (c[0] < max_iter) & jnp.any(_window(unflat(c[1]))[1] > 0)

    def body(c):
        H = _deflate(_window_step(unflat(c[1]), (c[0] % 10) == 9))
        return c[0] + 1, tuple(H[i][j] for i, j in idx)

    _, f = jax.lax.while_loop(cond, body, (jnp.asarray(0), tuple(H[i][j] for i, j in idx)))
    H = unflat(f)
    return jnp.stack([H[i][i] for i in range(n)])


# --- alternative 2: characteristic polynomial + Aberth–Ehrlich --------------------------------


def charpoly_aberth_eigvals(A, iters: int = 12):
    n = A.shape[0]
    M = [[A[i, j] for j in range(n)] for i in range(n)]
    c = sum(M[i][i] for i in range(n)) / n
    for i in range(n):
        M[i][i] = M[i][i] - c
    f2 = sum(_abs2(x) for r in M for x in r)
    s = jnp.where(f2 > 0, 1 / jnp.sqrt(jnp.where(f2 > 0, f2, 1.0)), 1.0)
    M = [[x * s for x in r] for r in M]

    def mm(X, Y):
        return [[sum(X[i][k] * Y[k][j] for k in range(n)) for j in range(n)] for i in range(n)]

    def tr(X, Y):
        return sum(X[i][j] * Y[j][i] for i in range(n) for j in range(n))

    pows = [M]
    while len(pows) < (n + 1) // 2:
        pows.append(mm(pows[-1], M))
    P = [None, sum(M[i][i] for i in range(n))]
    for k in range(2, n + 1):
        P.append(tr(pows[k // 2 - 1], pows[k - k // 2 - 1]))
    e = [jnp.ones_like(P[1])]
    for k in range(1, n + 1):
        e.append(sum((-1) ** (i - 1) * e[k - i] * P[i] for i in range(1, k + 1)) / k)
    a = [(-1) ** k * e[k] for k in range(n + 1)]
    ang = np.exp(1j * (2 * np.pi * np.arange(n) / n + 0.4))
    r = jnp.maximum(jnp.abs(a[n]) ** (1.0 / n), 1e-3)

    def body(_, z):
        z = list(z)
        for i in range(n):
            p, dp = jnp.ones_like(z[i]), jnp.zeros_like(z[i])
            for ak in a[1:]:
                dp, p = dp * z[i] + p, p * z[i] + ak
            N = p / jnp.where(dp != 0, dp, 1.0)
            S = sum(1 / (z[i] - z[j]) for j in range(n) if j != i)
            w = N / (1 - N * S)
            z[i] = z[i] - jnp.where(jnp.isfinite(w) & (p != 0), w, 0.0)
        return tuple(z)

    z = jax.lax.fori_loop(0, iters, body, tuple(r * ang[i] for i in range(n)))
    return jnp.stack([zi / s + c for zi in z])


# --- measurement -------------------------------------------------------------------------------


def _time(f, *args, repeat):
    jax.block_until_ready(f(*args))
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(f(*args))
        ts.append(time.perf_counter() - t)
    return min(ts)


def _compile(f, *args):
    """Compile seconds of a fresh ``jit`` (a new wrapper: no cached executable)."""
    t = time.perf_counter()
    jax.jit(lambda *a: f(*a)).lower(*args).compile()
    return time.perf_counter() - t


def families(n, B, rng, cu5=False):
    Z = rng.standard_normal((B, n, n)) + 1j * rng.standard_normal((B, n, n))
    g = (rng.standard_normal(B) + 1j * rng.standard_normal(B))[:, None, None]
    lam = 10 ** rng.uniform(-10, 3, (B, n)) * np.exp(2j * np.pi * rng.uniform(size=(B, n)))
    Q, _ = np.linalg.qr(Z)
    out = {
        "random": Z,
        "near-scalar 1e-3": g * np.eye(n) + 1e-3 * Z,
        "near-scalar 1e-6": g * np.eye(n) + 1e-6 * Z,
        "spread 1e-10…1e3": Q @ (lam[:, :, None] * np.conj(np.swapaxes(Q, 1, 2))),
        "Jordan block + 1e-12": g * np.eye(n) + np.eye(n, k=1) + 1e-12 * Z.real,
    }
    if cu5:
        out["cu5 posterior loops (20 draws × 1000 ω)"] = cu5_loops(20)
    return out


def cu5_loops(S):
    from hapid.control import Compensator, inverse_model_response
    from hapid.device import cu5
    from hapid.experiment import Protocol, estimate_frf, periodic_run
    from hapid.fit import fit_nls
    from hapid.uncertainty import laplace_samples, posterior_omega

    nls = fit_nls(estimate_frf(periodic_run(cu5(), Protocol(), noise_seed=0)))
    w = jnp.asarray(posterior_omega(1000))
    G = inverse_model_response(nls.model, Compensator.paper(), w)
    models = laplace_samples(nls, S, key=0).models(np.arange(S))
    P = jax.jit(jax.vmap(lambda m: m.P(1j * w)))(models)
    return np.asarray(jnp.einsum("dwij,wjk->dwik", P, G)).reshape(-1, 5, 5)


def err_ratio(e, A):
    """max over the family of ``|λ − λ_ref| / (1e-12‖A‖_F + 1e-10|λ_ref|)``, optimal matching."""
    ref = np.linalg.eigvals(A)
    n = A.shape[1]
    perms = np.array(list(itertools.permutations(range(n))))
    d = np.max(np.abs(e[:, perms] - ref[:, None, :]), axis=2)
    got = e[np.arange(len(e))[:, None], perms[np.argmin(d, axis=1)]]
    tol = 1e-12 * np.linalg.norm(A, axis=(1, 2))[:, None] + 1e-10 * np.abs(ref)
    return float(np.max(np.abs(got - ref) / tol))


def table(head, rows):
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(str(x) for x in r) + " |" for r in rows]
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    rep = 5 if args.quick else 15
    rng = np.random.default_rng(0)
    n = 5
    kernels = {
        "K.eigvals (in use: stage-wise QR)": K.eigvals,
        "window QR (one loop, all stages)": window_qr_eigvals,
        "charpoly + Aberth (12 it.)": charpoly_aberth_eigvals,
    }
    jitted = {k: jax.jit(f) for k, f in kernels.items()}
    lapack = jax.jit(jnp.linalg.eigvals)

    rows = []
    for name, f in jitted.items():
        r = [name]
        for B in (1000, 3000):
            A = jnp.asarray(rng.standard_normal((n, n, B)) + 1j * rng.standard_normal((n, n, B)))
            r.append(f"{_time(f, A, repeat=rep) / B * 1e6:.2f}")
        rows.append(r)
    r = ["LAPACK jnp.linalg.eigvals"]
    for B in (1000, 3000):
        A = jnp.asarray(rng.standard_normal((B, n, n)) + 1j * rng.standard_normal((B, n, n)))
        r.append(f"{_time(lapack, A, repeat=rep) / B * 1e6:.2f}")
    rows.append(r)
    print("## Eigenvalues, complex 5 × 5 (goal ≤ 0.6 µs per matrix)\n")
    print(table(["kernel", "µs / matrix, B = 1000", "µs / matrix, B = 3000"], rows))

    fam = families(n, 1000, rng, cu5=not args.quick)
    rows = []
    for fname, A in fam.items():
        Ae = K.to_entries(jnp.asarray(A))
        rows.append([fname] + [f"{err_ratio(np.asarray(f(Ae)).T, A):.2g}" for f in jitted.values()])
    print("\n## Max error vs numpy LAPACK, in units of 1e-12‖A‖_F + 1e-10|λ| (≤ 1 passes)\n")
    print(table(["family"] + list(kernels), rows))

    rows = []
    for m in (3, 5, 6):
        r = [str(m)]
        for B in (1000, 3000):
            a = jnp.asarray(rng.standard_normal((m, B)) + 1j * rng.standard_normal((m, B)))
            b = a + 0.5 * jnp.asarray(
                rng.standard_normal((m, B)) + 1j * rng.standard_normal((m, B))
            )
            old, new = jax.jit(pair_select_chain), jax.jit(K.pair_optimal)
            same = bool(jnp.all(old(a, b) == new(a, b)))
            r += [f"{_time(old, a, b, repeat=rep) / B * 1e6:.3f}",
                  f"{_time(new, a, b, repeat=rep) / B * 1e6:.3f}", "yes" if same else "NO"]  # fmt: skip
        rows.append(r)
    print("\n## Pairing of loci (µs per pair of eigenvalue sets; goal ≤ 0.15 at n = 5)\n")
    print(table(["n", "select chains, B=1000", "level-reduced (in use), B=1000", "same",
                 "select chains, B=3000", "level-reduced, B=3000", "same"], rows))  # fmt: skip

    A = jnp.zeros((n, n, 1001), jnp.complex128)  # shapes not compiled above
    a = jnp.zeros((n, 1001), jnp.complex128)
    rows = [[f"jit({k}) n = 5", f"{_compile(f, A):.1f} s"] for k, f in kernels.items()]
    rows.append(["jit(pair select chains), n = 5", f"{_compile(pair_select_chain, a, a):.1f} s"])
    rows.append(["jit(K.pair_optimal), n = 5", f"{_compile(K.pair_optimal, a, a):.1f} s"])
    rows.append(["loop_metrics 5 × 5, N = 1000 (first − warm)", f"{loop_metrics_compile():.1f} s"])
    print("\n## Compile times\n")
    print(table(["program", "compile"], rows))


def loop_metrics_compile():
    from hapid.control import loop_metrics

    rng = np.random.default_rng(5)
    n, N = 5, 1000
    w = jnp.asarray(np.logspace(-1, 4, N))
    P = jnp.asarray(rng.standard_normal((N, n, n)) + 1j * rng.standard_normal((N, n, n))) * 0.3
    G = jnp.broadcast_to(jnp.eye(n, dtype=jnp.complex128), (N, n, n))
    t = time.perf_counter()
    jax.block_until_ready(jax.tree.leaves(loop_metrics(P, G, w)))
    first = time.perf_counter() - t
    t = time.perf_counter()
    jax.block_until_ready(jax.tree.leaves(loop_metrics(P, G, w)))
    return first - (time.perf_counter() - t)


if __name__ == "__main__":
    main()
