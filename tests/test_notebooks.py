"""Execute the tutorial notebooks (fast mode) and check one real property of each.

Each notebook runs in a fresh kernel of *this* interpreter (a throw-away kernelspec pointing
at ``sys.executable``, so a system-wide ``python3`` kernel is never picked up), with
``HAPID_FAST=1`` and its outputs redirected to a temporary folder (``HAPID_NB_OUT``). After
the notebook, one extra cell prints a JSON probe of the notebook's own state.
"""

import json
import os
import sys
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
ipykernel_kernelspec = pytest.importorskip("ipykernel.kernelspec")

NB_DIR = Path(__file__).resolve().parent.parent / "notebooks"
KERNEL = "hapid-test-python"
CELL_TIMEOUT = 300
PROBE = "PROBE_JSON:"


@pytest.fixture(scope="module")
def kernel_env(tmp_path_factory):
    """A kernelspec for sys.executable in a temp prefix, found first via JUPYTER_PATH."""
    prefix = tmp_path_factory.mktemp("jupyter")
    ipykernel_kernelspec.install(kernel_name=KERNEL, prefix=str(prefix))
    spec = json.loads(
        (prefix / "share" / "jupyter" / "kernels" / KERNEL / "kernel.json").read_text()
    )
    assert Path(spec["argv"][0]).resolve() == Path(sys.executable).resolve()
    mp = pytest.MonkeyPatch()
    mp.setenv(
        "JUPYTER_PATH",
        os.pathsep.join([str(prefix / "share" / "jupyter"), os.environ.get("JUPYTER_PATH", "")]),
    )
    mp.setenv("HAPID_FAST", "1")
    mp.setenv("MPLBACKEND", "Agg")
    yield
    mp.undo()


def run_notebook(name: str, out_dir: Path, probe: str, setup: str = "") -> tuple[dict, float]:
    """Execute ``notebooks/<name>.ipynb`` with outputs under ``out_dir``; return the probe
    cell's JSON and the wall time of the notebook (probe excluded). ``setup``: code run in
    the probe cell before the probe expression is evaluated."""
    nb = nbformat.read(NB_DIR / f"{name}.ipynb", as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), (
        f"{name}: committed outputs"
    )
    nb.cells.append(
        nbformat.v4.new_code_cell(
            f"import json as _j\n{setup}\nprint({PROBE!r}, _j.dumps({probe}))"
        )
    )
    os.environ["HAPID_NB_OUT"] = str(out_dir)
    try:
        client = nbclient.NotebookClient(
            nb,
            timeout=CELL_TIMEOUT,
            kernel_name=KERNEL,
            resources={"metadata": {"path": str(NB_DIR)}},
        )
        t0 = time.perf_counter()
        client.execute()  # raises CellExecutionError on the first failing cell
        wall = time.perf_counter() - t0
    finally:
        os.environ.pop("HAPID_NB_OUT", None)
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            assert out.get("output_type") != "error", (
                f"{name}: {out.get('ename')}: {out.get('evalue')}"
            )
    text = "".join(
        o.get("text", "") for o in nb.cells[-1].outputs if o.get("output_type") == "stream"
    )
    line = next(ln for ln in text.splitlines() if ln.startswith(PROBE))
    print(f"{name}: {wall:.1f} s")
    return json.loads(line[len(PROBE) :]), wall


def test_quickstart_nls_model_has_no_crhp_roots(kernel_env, tmp_path):
    probe, _ = run_notebook(
        "01_quickstart",
        tmp_path,
        "{'hand': int(nls_crhp.hand), 'total': int(nls_crhp.total), 'ok': bool(res.ok), "
        "'stable': bool(reports['hapid NLS + PD'].stable)}",
    )
    assert probe["hand"] == 0 and probe["total"] == 0
    assert probe["ok"]
    assert probe["stable"]
    assert (tmp_path / "01_quickstart" / "step.png").exists()


@pytest.mark.slow  # CI budget: the paper scene again (tests/test_results_table.py and the scene tests cover its numbers)
def test_paper_notebook_writes_summary_with_both_fits(kernel_env, tmp_path):
    probe, _ = run_notebook("02_paper_reproduction", tmp_path, "sorted(summary['fits'])")
    assert probe == ["nls", "wls"]
    out = tmp_path / "02_paper_reproduction"
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["fits"]) == {"wls", "nls"}
    for k in range(5, 11):
        assert (out / f"fig{k}.png").stat().st_size > 0


_STATE_SPACE_REFERENCE = f"""
_TESTS = {str(Path(__file__).resolve().parent)!r}
import dataclasses as _dc
import jax as _jax
import numpy as _np
from hapid import ImpedanceModel as _IM
from hapid.closed_loop import closed_loop as _cl
from hapid.control import closed_loop_is_stable as _cls, impedance_ratio_state_space as _irs
from hapid.control import inverse_model_state_space as _ims
_K = 12
_sub = _dc.replace(ps, samples=ps.samples[:_K], log_prob=ps.log_prob[:_K])
_rc = robust_check(_sub, (res.model, g), max_samples=None)  # default: the continuous-plant grid
_G = _ims(res.model, g)
_ms = _sub.models()
_ss = [bool(_cls(_irs(_IM(m.total, m.hand)), _G))
       for m in (_jax.tree.map(lambda a, i=i: a[i], _ms) for i in range(_K))]
_dev0 = bool(_cl(dev, discretize_controller(res.model, g, dev.ts)).is_stable())
import sys as _sys
_sys.path.insert(0, _TESTS)
from oracle_loop import analyze_loop as _al
from hapid.uncertainty import posterior_omega as _po
_om = _po()
_Gr = _np.asarray(res.model.P_inv(1j * _om)) * _np.asarray(g.at_omega(_om))[:, None, None]
_res = [bool(_al(_np.asarray(m.P(1j * _om)), _Gr, _om, 0).nyquist_resolved)
        for m in (_jax.tree.map(lambda a, i=i: a[i], _ms) for i in range(_K))]
"""


@pytest.mark.slow  # CI budget (make test-all runs it)
def test_uncertainty_notebook_robust_verdicts_match_closed_loop_poles(kernel_env, tmp_path):
    probe, _ = run_notebook(
        "03_uncertainty_robustness",
        tmp_path,
        "{'p_post': p_stable, 'p_dev': rep_dev.p_stable, 'n_post': rep_post.n, 'n_dev': rep_dev.n, "
        "'dev0': bool(rep_dev.stable[0]), 'dev0_ss': _dev0, 'rc': [bool(x) for x in _rc.stable], 'ss': _ss, "
        "'resolved': _res}",
        setup=_STATE_SPACE_REFERENCE,
    )
    # independent references (state space, no frequency grid): the nominal device's sampled
    # loop (first of the device variants) and the first posterior draws' continuous loops
    assert probe["dev0"] == probe["dev0_ss"]
    # the robust check never calls a draw stable whose closed loop is unstable; it agrees with
    # the closed-loop poles wherever its grid resolves the Nyquist count, and a draw whose count
    # the grid does not resolve (stiffness near 0: the loop has not settled at 0.005 Hz) is
    # not called stable
    rc, ss, res = probe["rc"], probe["ss"], probe["resolved"]
    assert not any(r and not s for r, s in zip(rc, ss, strict=True))
    assert [r for r, ok in zip(rc, res, strict=True) if ok] == [
        s for s, ok in zip(ss, res, strict=True) if ok
    ]
    assert not any(r for r, ok in zip(rc, res, strict=True) if not ok) and sum(res) >= len(res) // 2
    assert probe["n_post"] == 40  # FAST: N_ROBUST posterior samples analysed
    assert probe["n_dev"] == 1 + 2 + 2  # nominal + two poses (±x) + two virtual subjects


@pytest.mark.slow  # ~30 s on 2 shared cores: three compiled fits and an H1 on two datasets
def test_lab_data_notebook_warns_on_real_data_and_recovers_the_truth(kernel_env, tmp_path):
    probe, _ = run_notebook(
        "05_lab_data",
        tmp_path,
        "{'full_med': float(fits[(7, 50, 'nls')].quality.median_db[0]), "
        "'full_warn': len(fits[(7, 50, 'nls')].quality.warnings), "
        "'mode_med': float(fits[(7, 11, 'wls')].quality.median_db[0]), "
        "'z_max': float(np.max(np.abs(zscore))), 'ok': bool(r.ok)}",
    )
    assert probe["full_med"] > -6 and probe["full_warn"] >= 1  # one M, B, K: several modes
    assert probe["mode_med"] < -15  # the first mode alone is second order
    assert probe["ok"] and probe["z_max"] < 4.5  # known M, B, K within the Laplace std
    assert (tmp_path / "05_lab_data" / "model.npz").exists()
