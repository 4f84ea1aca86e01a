"""Evidence-limited design (hapid.tune._evidence): the small-gain condition beyond the
measured band against numpy, its invariant (the Nyquist count beyond ω_e is the same for
every plant within the mismatch bound), the never-worse rule on the evidence, the cu5_soft
device variant, and (slow) the whole CLI route on a
device never used for tuning choices: the tuned g is stable on its true plant."""

from math import tau as TWO_PI

import numpy as np
import pytest

from hapid.control import Compensator, inverse_model_response
from hapid.tune import Choice
from hapid.tune._decision import compare
from hapid.tune._evidence import (
    KAPPA,
    beyond_gain,
    beyond_grid,
    certificate,
    evidence_from_frf,
    small_gain_constraint,
)
from tests.test_tune import _model

F_HZ = np.array([1.0, 2.0, 4.0, 8.0, 15.0, 30.0, 50.0, 80.0, 100.0])


def no_worse(start: dict, tuned: dict):
    """``(tuned g returned, reason)`` of the decision table on two re-check rows."""
    d = compare(start, tuned)
    assert d.choice in (Choice.TUNED, Choice.START)
    return d.keeps_tuned, d.reason


def _frf(model, scale):
    """A 'measured' FRF whose plant is ``scale·P̂``: Z_H = scale·Ẑ_H, Z_T = Ẑ_T."""
    om = TWO_PI * F_HZ
    s = 1j * om
    return {"omega": om, "Z_H": scale * np.asarray(model.Z_H(s)), "Z_T": np.asarray(model.Z_T(s))}


def test_mismatch_bound_and_certificate_match_numpy():
    model = _model(2, 0)
    ev = evidence_from_frf(_frf(model, 1.7), model)
    assert ev.mismatch == pytest.approx(1.7, rel=1e-9)  # σ̄(1.7 P̂ P̂⁻¹) = 1.7
    assert ev.omega_e == pytest.approx(TWO_PI * 100.0) and ev.g_max == pytest.approx(KAPPA / 1.7)
    g = Compensator.paper()
    om = np.geomspace(ev.omega_e, ev.omega_e * 10**1.5, 4000)
    ref = np.max(np.abs(np.asarray(g(1j * om)))) * 1.7
    assert beyond_gain(g, ev) == pytest.approx(ref, rel=2e-3)
    # the soft maximum bounds the true maximum from above, within log(N)/β
    c = float(small_gain_constraint(g, beyond_grid(ev), ev.g_max))
    hard = np.log(np.max(np.abs(np.asarray(g(1j * beyond_grid(ev)))))) - np.log(ev.g_max)
    assert hard <= c <= hard + np.log(beyond_grid(ev).size) / 60.0 + 1e-12
    # return difference of the measured loop: numpy reference, P = 1.7 P̂, G = g Ẑ_T Ẑ_H⁻¹
    G = np.asarray(inverse_model_response(model, g, ev.omega))
    rd = np.min(np.linalg.svd(np.eye(2) + 1.7 * np.asarray(model.P(1j * ev.omega)) @ G,
                              compute_uv=False)[:, -1])  # fmt: skip
    cert = certificate(ev, model, g)
    assert cert.frf_min_sigma_I_plus_L == pytest.approx(rd, rel=1e-9)
    assert cert.nominal_stable  # a PD model: Ẑ_H has no RHP roots, L = g I is stable
    assert cert.certified == bool(rd >= 0.5 and cert.beyond_loop_gain <= KAPPA)
    with pytest.raises(ValueError, match="kappa"):
        evidence_from_frf(_frf(model, 1.0), model, kappa=1.5)


def test_nominal_loop_is_unstable_when_the_hand_model_has_rhp_roots():
    """The certificate's nominal loop (``L = g I`` on the model's own plant, the controller's
    RHP poles counted): stable for a PD model, never for one whose Ẑ_H has an RHP root —
    ``G = g Ẑ_T Ẑ_H⁻¹`` cancels it unstably (closed form: det(I + g I) = (1 + g)ⁿ makes no
    encirclement to offset the controller's open-loop RHP pole)."""
    import hapid
    from hapid.control import controller_unstable_poles
    from hapid.tune._evidence import nominal_stable

    model = _model(2, 0)
    g = Compensator.paper()
    assert nominal_stable(model, g)
    h = model.hand
    bad = hapid.ImpedanceModel(hapid.SecondOrder(h.M, h.B, h.K - 2.0 * np.trace(np.asarray(h.K)) * np.eye(2)),
                               model.total)  # fmt: skip
    assert int(controller_unstable_poles(bad, g)) > 0
    assert not nominal_stable(bad, g)


def test_certificate_judges_the_measured_loci_like_the_analysis():
    """A non-normal measured plant P = A P̂ (L = g A): the certificate's loci distance is
    numpy's min |1 + g λ_i(A)|, it is never below the return difference σ̲(I + g A), and
    ``certified`` follows the loci — the rule of the tuner's disc and of the loci margins —
    where the two figures sit on opposite sides of the floor."""
    model = _model(2, 0)
    A = np.array([[1.0, 2.5], [0.0, 1.0]])  # eigenvalues 1, 1; far from normal
    s = 1j * TWO_PI * F_HZ
    data = {
        "omega": TWO_PI * F_HZ,
        "Z_H": A @ np.asarray(model.Z_H(s)),
        "Z_T": np.asarray(model.Z_T(s)),
    }
    ev = evidence_from_frf(data, model)
    g = Compensator.paper()
    gv = np.asarray(g(s))
    loci = np.min(np.abs(1.0 + gv[:, None] * np.linalg.eigvals(A)[None]))
    sig = np.min(np.linalg.svd(np.eye(2) + gv[:, None, None] * A, compute_uv=False)[:, -1])
    cert = certificate(ev, model, g)
    # A is defective (a Jordan block): its eigenvalues, and so the loci, are accurate to
    # ~√eps only, and LAPACK builds differ at 1e-9 (measured 2.6e-9 between two machines)
    assert cert.frf_min_loci_distance == pytest.approx(loci, rel=1e-7)
    assert cert.frf_min_sigma_I_plus_L == pytest.approx(sig, rel=1e-9)
    assert sig < 0.5 <= loci  # the case where the two rules disagree
    assert cert.certified == bool(cert.nominal_stable and cert.beyond_loop_gain <= ev.kappa)


def test_small_gain_fixes_the_nyquist_phase_beyond_the_evidence():
    """The invariant behind the method: any two loops with σ̄(L) ≤ κ < 1 on ω ≥ ω_e collect
    the same net phase of det(I + L) there, however their phases differ (a delay, a mode)."""
    rng = np.random.default_rng(3)
    om = np.geomspace(1.0, 50.0, 3000)
    n = 3
    for _ in range(20):
        phase = []
        for _ in range(2):
            A = rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))
            B = rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))
            tau = rng.uniform(0.0, 0.5)  # an unknown delay: any amount of phase
            L = (A[None] + B[None] / (1 + 1j * om[:, None, None])) * np.exp(-1j * om * tau)[
                :, None, None
            ]
            L *= KAPPA / np.linalg.svd(L, compute_uv=False)[:, :1, None]  # σ̄(L) = κ exactly
            d = np.linalg.det(np.eye(n) + L)
            phase.append(np.unwrap(np.angle(d))[-1] - np.unwrap(np.angle(d))[0])
        # each 1 + λ_i stays in the disc of radius κ around 1: |net phase| < n·π, and both
        # loops' phases differ by less than one winding
        assert all(abs(p) < n * np.arcsin(KAPPA) * 2 + 1e-9 for p in phase)
        assert abs(phase[0] - phase[1]) < 2 * np.pi


def test_never_worse_decides_on_the_evidence_first():
    base = {"true_stable": True, "posterior_frac_meeting_margins": 0.8,
            "posterior_iso_bandwidth_hz_q50": 4.0, "evidence_hz": 100.0}  # fmt: skip
    good = {"certified": True, "frf_min_loci_distance": 0.6, "beyond_loop_gain": 0.4}
    bad = {"certified": False, "frf_min_loci_distance": 0.3, "beyond_loop_gain": 0.7}
    better_draws = {"posterior_frac_meeting_margins": 0.95, "posterior_iso_bandwidth_hz_q50": 6.0}
    ok, why = no_worse(base | good, base | bad | better_draws)
    assert not ok and "holds on the evidence" in why
    ok, why = no_worse(base | bad, base | good | {"posterior_iso_bandwidth_hz_q50": 3.0})
    assert ok and "the start does not" in why
    # neither certified: the tuned g may not raise the beyond-band gain bound
    ok, why = no_worse(base | bad, base | bad | better_draws | {"beyond_loop_gain": 0.9})
    assert not ok and "beyond the evidence" in why
    # neither certified: a tuned loop closer to −1 on the measured FRF is not kept, even
    # with better draws and the start's loci distance above the floor
    mid = {"certified": False, "frf_min_loci_distance": 0.55, "beyond_loop_gain": 0.7}
    ok, why = no_worse(base | mid, base | mid | better_draws | {"frf_min_loci_distance": 0.52})
    assert not ok and "neither is certified" in why and "closer to −1" in why
    ok, why = no_worse(base | mid | {"nominal_stable": True},
                       base | mid | better_draws | {"nominal_stable": False})  # fmt: skip
    assert not ok and "model's own plant" in why
    # … and better on the same evidence and on the draws: kept
    ok, why = no_worse(base | mid, base | mid | better_draws | {"frf_min_loci_distance": 0.56})
    assert ok and "margins met 80.0 → 95.0 %" in why
    # no better on the draws: the start stays, however the evidence figures moved
    assert not no_worse(base | mid, base | mid | {"frf_min_loci_distance": 0.6})[0]
    assert no_worse(base | good, base | good | better_draws)[0]


def test_decision_table_names_the_deciding_rule_in_order():
    """Each row of the decision table decides where it should, in the table's order: an
    unstable true plant beats every other figure; the certificate beats the draws; with
    nothing else to say, the held-out draws decide. The Decision is typed and its summary is
    strict JSON."""
    import json

    from hapid.tune._decision import RULES, Decision

    assert [name for name, _ in RULES] == ["true plant", "certificate", "evidence figures",
                                           "measured FRF", "held out"]  # fmt: skip
    base = {"true_stable": True, "posterior_frac_meeting_margins": 0.8,
            "posterior_iso_bandwidth_hz_q50": 4.0, "evidence_hz": 100.0}  # fmt: skip
    good = {"certified": True, "frf_min_loci_distance": 0.6, "beyond_loop_gain": 0.4}
    bad = {"certified": False, "frf_min_loci_distance": 0.3, "beyond_loop_gain": 0.7}
    better = {"posterior_frac_meeting_margins": 0.95, "posterior_iso_bandwidth_hz_q50": 6.0}
    d = compare(base | bad, base | good | better | {"true_stable": False})
    assert (d.rule, d.choice) == ("true plant", Choice.START)
    d = compare(base | good, base | bad | better)
    assert (d.rule, d.choice) == ("certificate", Choice.START)
    d = compare(base | good, base | good | better)
    assert (d.rule, d.choice) == ("held out", Choice.TUNED) and d.keeps_tuned
    assert isinstance(d, Decision) and json.loads(json.dumps(d.summary()))["choice"] == "tuned"


def test_cu5_soft_is_cu5_with_more_delay_and_compliant_rods(tmp_path):
    from hapid.cli import main
    from hapid.device import cu5, cu5_soft

    a, b = cu5(), cu5_soft()
    assert b.delay_samples == a.delay_samples + 1
    np.testing.assert_allclose(np.asarray(b.mechanism.k_t), np.asarray(a.mechanism.k_t) / 2)
    np.testing.assert_allclose(np.asarray(b.mechanism.k_s), np.asarray(a.mechanism.k_s) / 2)
    np.testing.assert_array_equal(np.asarray(b.mechanism.m2), np.asarray(a.mechanism.m2))
    assert main(["plant", "--rod-compliance", "0", "--out", str(tmp_path / "x.npz")]) == 2
    assert not (tmp_path / "x.npz").exists()
    with pytest.raises(ValueError, match="compliance"):
        cu5(rod_compliance=-1.0)


@pytest.mark.slow
def test_cli_plant_rod_compliance_matches_the_preset(tmp_path):
    from hapid.cli import main
    from hapid.device import preset
    from hapid.io import load_frf

    fp = tmp_path / "p.npz"
    assert main(["plant", "--device", "cu5", "--delay", "2", "--rod-compliance", "2", "--n-freq", "12",
                 "--out", str(fp)]) == 0  # fmt: skip
    f = load_frf(fp)
    np.testing.assert_allclose(np.asarray(f.P), np.asarray(preset("cu5_soft").sampled_P(np.asarray(f.omega))),
                               rtol=1e-10, atol=1e-12)  # fmt: skip


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_cli_route_tuned_g_is_stable_on_a_device_not_used_for_tuning(tmp_path):
    """cu5_soft (never used to choose tuning settings): simulate → frf → nls → Laplace
    posterior → ``hapid tune --frf`` → ``hapid analyze --design --frf true_plant
    --continuous``. Whatever the tuner returns, it is stable on the true plant, and the route
    runs end to end."""
    import json

    from hapid import io
    from hapid.cli import main
    from hapid.device import cu5_soft
    from hapid.io import load_samples
    from hapid.tune import load_design, true_plant_loop

    d = tmp_path
    for argv in (["simulate", "--device", "cu5_soft", "--out", str(d / "run.npz")],
                 ["frf", str(d / "run.npz"), "--out", str(d / "frf.npz")],
                 ["fit", str(d / "frf.npz"), "--method", "nls", "--f-max-hz", "40", "--out", str(d / "nls.npz")],
                 ["posterior", str(d / "frf.npz"), "--method", "laplace", "--samples", "120",
                  "--out", str(d / "s.npz")],
                 ["tune", "--model", str(d / "nls.npz"), "--samples", str(d / "s.npz"), "--frf",
                  str(d / "frf.npz"), "--fs", "1000", "--n-train", "24", "--n-holdout", "60", "--max-steps", "120",
                  "--out", str(d / "design.npz"), "--report", str(d / "tune.json")],
                 ["plant", "--device", "cu5_soft", "--out", str(d / "true.npz")],
                 ["analyze", "--model", str(d / "nls.npz"), "--design", str(d / "design.npz"),
                  "--frf", str(d / "true.npz"), "--continuous", "--out", str(d / "a.json")]):  # fmt: skip
        assert main(argv) == 0, argv
    g, info = load_design(d / "design.npz")
    model = io.load_model(d / "nls.npz")
    assert true_plant_loop(Compensator.paper(), model, cu5_soft()).numbers()["stable"]  # the start
    t = true_plant_loop(g, model, cu5_soft()).numbers()
    assert t["stable"], t
    assert json.loads((d / "a.json").read_text())["stable"]
    assert "evidence" in info["families"] and info["families"]["evidence"]["source"] == "frf"
    # without --frf: the measured FRF the samples file stores (every frequency, 1–100 Hz) is the
    # evidence and the draws are loop draws conditioned on it
    assert np.array_equal(
        load_samples(d / "s.npz").measured["omega"], io.load_frf(d / "frf.npz").omega
    )
    assert main(["tune", "--model", str(d / "nls.npz"), "--samples", str(d / "s.npz"), "--n-train", "24",
                 "--n-holdout", "60", "--max-steps", "120", "--out", str(d / "d2.npz"),
                 "--report", str(d / "t2.json")]) == 0  # fmt: skip
    g2, _ = load_design(d / "d2.npz")
    assert true_plant_loop(g2, model, cu5_soft()).numbers()["stable"]
    assert json.loads((d / "t2.json").read_text())["tuned"]["evidence_hz"] == pytest.approx(
        100.0, rel=0.01
    )
    rep = json.loads((d / "tune.json").read_text())
    assert {"certified", "beyond_loop_gain", "frf_min_sigma_I_plus_L"} <= set(rep["tuned"])


def test_fit_band_default_rule():
    from types import SimpleNamespace as NS

    from hapid._cli_fit import _band, _default_f_max
    from hapid.defaults import FIT_BAND_HZ

    f = np.arange(1.0, 101.0)
    assert _default_f_max(NS(f_max_hz=None, method="nls"), True) == FIT_BAND_HZ == 40.0
    assert _default_f_max(NS(f_max_hz=None, method="nls"), False) is None  # single impedance
    assert _default_f_max(NS(f_max_hz=None, method="wls"), True) is None
    assert _default_f_max(NS(f_max_hz=80.0, method="nls"), True) == 80.0
    assert _band(NS(f_min_hz=None, f_max_hz=None), f, 40.0) == (0.0, 40.0)
    assert _band(NS(f_min_hz=2.0, f_max_hz=None), f) == (2.0, np.inf)


@pytest.mark.slow
def test_fit_nls_on_the_haptic_pair_defaults_to_the_40_hz_band(tmp_path, capsys):
    """``hapid fit --method nls`` without a band fits 1–40 Hz of the haptic pair (the band of
    ``hapid posterior``), says so, and stores that band; WLS keeps every frequency."""
    from hapid.cli import main

    fp = tmp_path / "frf.npz"
    assert main(["plant", "--device", "tripod3", "--f-min-hz", "1", "--f-max-hz", "100",
                 "--n-freq", "30", "--out", str(fp)]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["fit", str(fp), "--method", "nls", "--out", str(tmp_path / "m.npz")]) == 0
    out = capsys.readouterr().out
    assert "default for nls and ml on the haptic pair: up to 40 Hz" in out
    f_q = np.load(tmp_path / "m.npz")["quality_freq_hz"]
    assert f_q.max() <= 40.0 and f_q.max() > 30.0
    assert main(["fit", str(fp), "--method", "wls", "--out", str(tmp_path / "w.npz")]) == 0
    assert np.load(tmp_path / "w.npz")["quality_freq_hz"].max() > 90.0


def test_uncertified_design_gets_a_warning_line():
    """``hapid tune`` prints a warning naming the failed evidence figures when the returned
    design is not certified, and nothing when it is."""
    from hapid.cli import uncertified_warning

    row = {"certified": False, "frf_min_loci_distance": 0.476, "beyond_loop_gain": 0.48,
           "evidence_hz": 100.0, "nominal_stable": True}  # fmt: skip
    w = uncertified_warning(row)
    assert w.startswith("WARNING") and "NOT certified" in w and "0.476" in w and "100 Hz" in w
    assert uncertified_warning(row | {"certified": True}) == ""


def test_certified_gain_is_the_largest_gain_the_evidence_certifies():
    """The certified fallback's gain: a g with 30× the paper gain is not certified on an FRF
    of a second-order truth with 2 ms of delay; :func:`certified_gain` returns the α at which
    it is, and 10 % more gain is not (the bisection's boundary), each checked by the
    certificate itself."""
    import equinox as eqx
    from helpers_fit import random_truth, synthetic_frf

    from hapid.control import Compensator
    from hapid.tune._decision import certified_gain
    from hapid.tune._evidence import certificate, evidence_from_frf

    truth = random_truth(2, seed=3)
    frf = synthetic_frf(truth, rel_noise=1e-3, seed=4)
    w = np.asarray(frf.omega)
    delay = np.exp(-1j * w * 2e-3)[:, None, None]
    src = {"omega": w, "Z_H": np.asarray(frf.Z_H) * delay, "Z_T": np.asarray(frf.Z_T)}
    ev = evidence_from_frf(src, truth)
    g0 = Compensator.paper()
    g = eqx.tree_at(lambda c: c.k, g0, g0.k * 30.0)
    scaled = lambda a: eqx.tree_at(lambda c: c.k, g, g.k * a)  # noqa: E731
    assert not certificate(ev, truth, g).certified
    a = certified_gain(g, ev, truth)
    assert a is not None and 0.0 < a < 1.0
    assert certificate(ev, truth, scaled(a)).certified
    assert not certificate(ev, truth, scaled(min(1.0, 1.1 * a))).certified


def test_fallback_prefers_certified_candidates_at_the_chance_level():
    """The certified fallback's choice (hapid.tune._decision.pick_fallback): a candidate at the
    chance level wins over one below it; with none at it a certified chosen design is kept
    (lowering the gain would trade one failed figure for another); an uncertified chosen
    design is replaced by the better certified candidate; no candidate, no change."""
    from hapid.tune._decision import pick_fallback

    def row(frac, bw):
        return {"certified": True, "posterior_frac_meeting_margins": frac,
                "posterior_iso_bandwidth_hz_q50": bw}  # fmt: skip

    low, high = ("start", 0.2, None, row(0.10, 0.7)), ("tuned", 0.5, None, row(0.99, 3.0))
    assert pick_fallback([low, high], {"certified": False}, 0.975)[0] == "tuned"
    assert pick_fallback([high, low], {"certified": True}, 0.975)[0] == "tuned"
    assert pick_fallback([low], {"certified": True}, 0.975) is None  # keep the chosen g
    assert pick_fallback([low], {"certified": False}, 0.975)[0] == "start"
    assert pick_fallback([], {"certified": False}, 0.975) is None
    # two below the level, chosen uncertified: the better one by no_worse (more draws meet)
    a, b = ("start", 0.2, None, row(0.10, 0.7)), ("tuned", 0.3, None, row(0.50, 0.5))
    assert pick_fallback([a, b], {"certified": False}, 0.975)[0] == "tuned"
