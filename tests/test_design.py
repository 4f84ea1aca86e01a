"""``hapid design``: its numbers are the single commands' numbers, the page is self-contained,
the JSON strict, the stage cache recomputes only what an option changes; a lab file with a
single impedance gives fits and no controller."""

from __future__ import annotations

import base64
import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from hapid import io
from hapid.cli import main
from hapid.design import check_of, delivered
from hapid.impedance import ImpedanceModel, SecondOrder
from hapid.impedance_frf import as_impedance_frf
from hapid.tune import load_design
from hapid.uncertainty import fit_loop_gp, loop_gp_mean
from hapid.uncertainty._loopgp import loop_gp_draws
from hapid.verdict import Verdict


class _Page(HTMLParser):
    """Every tag's URL attributes; images' sources; tags that load things."""

    def __init__(self):
        super().__init__()
        self.imgs, self.urls, self.loaders = [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.imgs.append(a.get("src", ""))
        if tag in ("script", "link", "iframe", "object", "embed"):
            self.loaders.append(tag)
        for k in ("href", "src", "action"):
            if k in a:
                self.urls.append(a[k])


def _no_constant(c):
    raise ValueError(f"non-strict JSON constant {c}")


def _check_outputs(d: Path) -> dict:
    """report.json strict, report.html self-contained with every figure as a PNG data URI;
    every figure also as PNG and PDF files. Returns the report numbers."""
    numbers = json.loads((d / "report.json").read_text(), parse_constant=_no_constant)
    page = _Page()
    page.feed((d / "report.html").read_text())
    page.close()
    assert page.loaders == []
    assert all(u.startswith("data:image/png;base64,") for u in page.urls), page.urls
    assert len(page.imgs) == len(numbers["figures"]) > 0
    for src in page.imgs:
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    for f in numbers["figures"]:
        assert (d / f"{f['name']}.png").stat().st_size > 0
        assert (d / f"{f['name']}.pdf").read_bytes()[:4] == b"%PDF"
    return numbers


def _same_model(a, b):
    for part in ("hand", "mechanism"):
        for m in ("M", "B", "K"):
            np.testing.assert_array_equal(
                getattr(getattr(a, part), m), getattr(getattr(b, part), m)
            )


def _run(args):
    assert main([str(x) for x in args]) == 0


def test_design_fits_are_the_single_commands_and_a_changed_option_reruns_only_its_stage(tmp_path):
    """tripod3, short protocol, the fit stages only: the design's FRF and models are the
    single commands' files to the bit; a changed NLS band recomputes the NLS stage alone."""
    run, d, s, cache = tmp_path / "run.npz", tmp_path / "out", tmp_path / "single", tmp_path / "c"
    _run(["simulate", "--device", "tripod3", "--periods", "2", "--out", run])
    design = ["design", run, "--out", d, "--only", "wls", "--only", "nls", "--cache", cache]
    _run(design)
    s.mkdir()
    _run(["frf", run, "--out", s / "frf.npz"])
    _run(["fit", s / "frf.npz", "--method", "wls", "--positize", "--out", s / "wls.npz"])
    _run(["fit", s / "frf.npz", "--method", "nls", "--f-max-hz", "40", "--out", s / "nls.npz"])
    np.testing.assert_array_equal(io.load_frf(d / "frf.npz").Z_H, io.load_frf(s / "frf.npz").Z_H)
    for m in ("wls", "nls"):
        _same_model(io.load_model(d / f"{m}.npz"), io.load_model(s / f"{m}.npz"))
    numbers = _check_outputs(d)
    meta = io.load_model_metadata(s / "nls.npz")
    q = numbers["fits"]["nls"]["quality"]
    for k, block in enumerate(meta["quality_blocks"]):
        assert q[str(block)]["median_rel_err_db"] == float(meta["quality_median_db"][k])
        assert q[str(block)]["max_rel_err_db"] == float(meta["quality_max_db"][k])
    assert {f["name"] for f in numbers["figures"]} == {"frf_Z_H", "frf_Z_T", "pphat"}
    assert numbers["stages"]["skipped"] == ["ml", "posterior", "robust", "tune"]
    assert numbers["verdict"]["checks"] == [] and "skipped" in numbers["controller"]
    # one option changed: only the NLS stage is recomputed. 42 Hz keeps the band's
    # frequencies (the protocol has none in 40–45 Hz): the recomputed stage reuses the
    # compiled fit and must give the same model again
    _run([*design, "--f-max-hz", "42"])
    st = json.loads((d / "report.json").read_text())["stages"]
    assert st["computed"] == ["input", "nls"] and set(st["cached"]) == {"frf", "wls"}
    _same_model(io.load_model(d / "wls.npz"), io.load_model(s / "wls.npz"))
    _same_model(io.load_model(d / "nls.npz"), io.load_model(s / "nls.npz"))


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_design_robust_check_is_the_single_command_and_its_verdict(tmp_path):
    """tripod3: the robust stage's numbers are ``hapid robust``'s; each model's check is
    failed / not established / passed as its report says."""
    run, d, s = tmp_path / "run.npz", tmp_path / "out", tmp_path / "single"
    _run(["simulate", "--device", "tripod3", "--periods", "2", "--out", run])
    _run(["design", run, "--out", d, "--skip", "ml", "--skip", "posterior", "--no-cache",
          "--max-samples", "20"])  # fmt: skip
    s.mkdir()
    _run(["frf", run, "--out", s / "frf.npz"])
    _run(["fit", s / "frf.npz", "--method", "wls", "--positize", "--out", s / "wls.npz"])
    _run(["fit", s / "frf.npz", "--method", "nls", "--f-max-hz", "40", "--out", s / "nls.npz"])
    _run(["robust", "--frf", s / "frf.npz", "--model", s / "wls.npz", "--model", s / "nls.npz",
          "--max-samples", "20", "--out", s / "robust.json"])  # fmt: skip
    single = json.loads((s / "robust.json").read_text())
    assert json.loads((d / "robust.json").read_text()) == single
    numbers = _check_outputs(d)
    assert numbers["robust"] == single  # the report's numbers are the command's
    assert {f["name"] for f in numbers["figures"]} >= {"loci", "sigma_T_minus_I", "robust"}
    for c, m in zip(numbers["verdict"]["checks"], ("wls", "nls"), strict=True):
        r = single[m]["posterior"]  # hapid robust's own three-valued verdict
        assert (c["verdict"], c["reason"], c["remedy"]) == (r["verdict"], r["reason"], r["remedy"])
        assert (c["verdict"] == "passed") == (c["reason"] == "")


def _records(truth: SecondOrder, fs: float, T: int, E: int, noise: float, seed: int):
    """White forces and the exact periodic displacement (one period per record) plus noise."""
    rng = np.random.default_rng(seed)
    F = rng.standard_normal((E, T, truth.n))
    w = 2 * np.pi * np.fft.rfftfreq(T, 1 / fs)
    Zw = np.array(truth.at_omega(w))
    Zw[0] = np.asarray(truth.K)
    X = np.einsum("kij,ekj->eki", np.linalg.inv(Zw), np.fft.rfft(F, axis=1))
    Y = np.fft.irfft(X, n=T, axis=1)
    return F, Y + noise * np.std(Y) * rng.standard_normal(Y.shape)


def test_design_on_a_lab_file_fits_a_single_impedance_and_makes_no_controller(tmp_path):
    truth = SecondOrder(np.diag([0.8, 1.5]), np.array([[12.0, 2.0], [2.0, 9.0]]),
                        np.array([[4e3, 500.0], [500.0, 3e3]]))  # fmt: skip
    F, Y = _records(truth, fs=200.0, T=2**13, E=2, noise=0.01, seed=3)
    ts, d = tmp_path / "ts.npz", tmp_path / "out"
    np.savez(ts, fs_hz=200.0, force=F, response=Y)
    lab = ["--nperseg", "512", "--lab-f-min-hz", "2", "--lab-f-max-hz", "60"]
    _run(["design", ts, "--out", d, "--no-cache", *lab])
    numbers = _check_outputs(d)
    assert numbers["verdict"]["checks"] == [] and "no controller" in numbers["controller"]
    assert numbers["robust"] is None and numbers["tune"] is None
    assert {f["name"] for f in numbers["figures"]} == {"frf_Z", "coherence"}
    assert not (d / "design.npz").exists()
    # the same fit as the single commands, and it recovers the truth
    _run(["frf", ts, "--h1", "--nperseg", "512", "--f-min-hz", "2", "--f-max-hz", "60",
          "--out", tmp_path / "z.npz"])  # fmt: skip
    # the coherence the report shows is the single command's H1 coherence: 512-sample Welch
    # segments of white noise, 1 % noise: high but < 1 (numpy's median and minimum of the file)
    g = np.asarray(io.load_impedance_frf(tmp_path / "z.npz").coherence)
    coh = numbers["frf"]["coherence"]["Z"]
    assert (coh["median"], coh["min"]) == (float(np.median(g)), float(np.min(g)))
    assert 0.9 < coh["median"] < 1.0 and g.shape == (numbers["frf"]["n_freq"], 2)
    _run(["fit", tmp_path / "z.npz", "--method", "nls", "--out", tmp_path / "nls.npz"])
    a, b = io.load_impedance_model(d / "nls.npz"), io.load_impedance_model(tmp_path / "nls.npz")
    for m in ("M", "B", "K"):
        np.testing.assert_array_equal(getattr(a, m), getattr(b, m))
        rel = np.linalg.norm(getattr(a, m) - getattr(truth, m)) / np.linalg.norm(getattr(truth, m))
        assert rel < 0.05, (m, rel)
    assert "no controller" in (d / "report.html").read_text()


def test_design_refuses_a_model_file_and_an_inapplicable_stage_and_writes_nothing(tmp_path, capsys):
    model = tmp_path / "m.npz"
    io.save_impedance_model(model, SecondOrder(np.eye(2), np.eye(2), np.eye(2)))
    assert main(["design", str(model), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hapid design takes a run file" in err[0]
    z = tmp_path / "z.npz"
    io.save_impedance_frf(z, _impedance_frf())
    assert main(["design", str(z), "--out", str(tmp_path / "o"), "--skip", "tune"]) == 2
    assert "not part of this design" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def _impedance_frf():
    f = np.linspace(1, 50, 20)
    Z = np.array(SecondOrder(np.eye(2), np.eye(2), 100 * np.eye(2)).at_omega(2 * np.pi * f))
    return as_impedance_frf(f, Z, 0.01 * np.abs(Z))


def test_loop_gp_mean_is_the_mean_of_the_loop_draws():
    """loop_gp_mean (the plant the report's loci are drawn on) against the sample mean of
    loop_gp_draws, inside, below and above the measured band."""
    rng = np.random.default_rng(0)
    n = 2
    model = ImpedanceModel.from_hand_mechanism(
        SecondOrder(np.eye(n), 5 * np.eye(n), 1e3 * np.eye(n)),
        SecondOrder(0.5 * np.eye(n), 2 * np.eye(n), 0 * np.eye(n)),
    )
    om = 2 * np.pi * np.geomspace(1, 60, 25)
    Ph = np.asarray(model.P(1j * om))
    Q = np.eye(n) + 0.2 * np.sin(np.log(om))[:, None, None] * np.ones((n, n))
    Q = Q + 0.02 * (rng.standard_normal(Q.shape) + 1j * rng.standard_normal(Q.shape))
    gp = fit_loop_gp(om, Q @ Ph, model)
    w = 2 * np.pi * np.array([0.3, 0.8, 3.0, 17.0, 55.0, 80.0, 300.0])
    draws = loop_gp_draws(gp, w, 20000, seed=1)
    mean, sd = draws.mean(0), draws.std(0) / np.sqrt(draws.shape[0])
    assert np.all(np.abs(loop_gp_mean(gp, w) - mean) <= 5 * sd + 1e-12)


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_design_cu5_numbers_are_the_single_commands(tmp_path):
    """cu5 with the paper protocol: ML, the Laplace posterior, the robust check of the paper
    g on three models and the tuned g — every number as the single commands make it."""
    run, d, s = tmp_path / "run.npz", tmp_path / "out", tmp_path / "single"
    _run(["simulate", "--device", "cu5", "--out", run])
    _run(["design", run, "--out", d, "--max-samples", "100", "--no-cache"])
    s.mkdir()
    _run(["frf", run, "--out", s / "frf.npz"])
    _run(["fit", s / "frf.npz", "--method", "nls", "--f-max-hz", "40", "--out", s / "nls.npz"])
    _run(["fit", run, "--method", "ml", "--f-max-hz", "40", "--out", s / "ml.npz"])
    _run(["fit", s / "frf.npz", "--method", "wls", "--positize", "--out", s / "wls.npz"])
    _run(["posterior", s / "frf.npz", "--method", "laplace", "--f-max-hz", "40", "--seed", "0",
          "--samples", "4000", "--out", s / "samples.npz"])  # fmt: skip
    _run(["robust", "--frf", s / "frf.npz", "--model", s / "wls.npz", "--model", s / "nls.npz",
          "--model", s / "ml.npz", "--max-samples", "100", "--out", s / "robust.json"])  # fmt: skip
    _run(["tune", "--model", s / "nls.npz", "--samples", s / "samples.npz", "--fs", "1000",
          "--seed", "0", "--out", s / "design.npz", "--report", s / "tune.json"])  # fmt: skip
    for m in ("wls", "nls", "ml"):
        _same_model(io.load_model(d / f"{m}.npz"), io.load_model(s / f"{m}.npz"))
    numbers = _check_outputs(d)
    assert numbers["robust"] == json.loads((s / "robust.json").read_text())
    g_d, info_d = load_design(d / "design.npz")
    g_s, info_s = load_design(s / "design.npz")
    for f in ("k", "lag_zeros", "lag_poles", "notch_omega", "notch_zeta_num", "lowpass"):
        np.testing.assert_array_equal(getattr(g_d, f), getattr(g_s, f))

    def numbers_of(table):  # every row's numbers but its wall time (validate_s)
        return {r: {k: v for k, v in row.items() if k != "validate_s"} for r, row in table.items()}

    assert numbers_of(io.jsonable(info_d["table"])) == numbers_of(io.jsonable(info_s["table"]))
    assert numbers_of(numbers["tune"]["table"]) == numbers_of(io.jsonable(info_s["table"]))
    assert len(numbers["verdict"]["checks"]) == 4  # paper g on 3 models + the tuned g


def test_check_of_is_three_valued_and_the_delivered_controller_decides():
    failed = check_of("paper g, WLS", False, ["|GM| short by 1 dB", "|PM| short by 2°"], "w")
    assert (
        failed.verdict is Verdict.FAILED and failed.reason == "|GM| short by 1 dB; |PM| short by 2°"
    )
    ne = check_of("paper g, NLS", True, [], "loop gain above 100 Hz 0.7", "measure higher")
    assert ne.verdict is Verdict.NOT_ESTABLISHED and (ne.reason, ne.remedy) == (
        "loop gain above 100 Hz 0.7",
        "measure higher",
    )
    ok = check_of("tuned g, NLS model", True, [])
    assert ok.verdict is Verdict.PASSED and ok.ok
    assert delivered([failed, ne, ok]) is Verdict.PASSED  # the tuned g is what is delivered
    assert delivered([ok.__class__(Verdict.PASSED, name="paper g"), ne]) is Verdict.NOT_ESTABLISHED
    assert delivered([failed, ne]) is Verdict.FAILED
