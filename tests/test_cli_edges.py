"""Regression tests of issue 16's first list: each bad input ends in exit 2 with one
``hapid: error:`` line naming the problem — no traceback, no numpy warning, no file written.
All in-process and before any real work, so the whole file runs in a few seconds."""

from __future__ import annotations

import argparse
import zipfile

import numpy as np
import pytest
from helpers_cli import assert_clean_error, write_valid_files

from hapid import io as hio
from hapid._cli_checks import options, rule_for
from hapid.cli import build_parser


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("edge")
    return d, write_valid_files(d)


# ---- tracebacks -----------------------------------------------------------------------------
def test_zero_byte_npz(files):
    d, _ = files
    (d / "empty.npz").write_bytes(b"")
    assert_clean_error(["frf", "empty.npz", "--out", "x.npz"], d, "empty.npz: empty file (0 bytes)")
    assert_clean_error(["fit", "empty.npz", "--out", "m.npz"], d, "expected an FRF file")


def test_truncated_zip_names_file_and_leaks_no_handle(files):
    d, f = files
    raw = f["run"].read_bytes()
    (d / "trunc.npz").write_bytes(raw[: len(raw) // 2])
    line = assert_clean_error(["frf", "trunc.npz", "--out", "x.npz"], d, "trunc.npz")
    assert "expected a run file" in line


def test_simulate_period_zero(files):
    assert_clean_error(["simulate", "--period", "0", "--out", "r.npz"], files[0],
                       "--period must be an integer in [2, 1000000], got 0")  # fmt: skip


def test_analyze_frf_fs_zero(files):
    assert_clean_error(["analyze", "--model", "model.npz", "--frf", "frf.npz", "--fs", "0"],
                       files[0], "--fs must be > 0 Hz, got 0")  # fmt: skip


def test_simulate_fs_zero_without_numpy_warnings(files):
    assert_clean_error(
        ["simulate", "--fs", "0", "--out", "r.npz"], files[0], "--fs must be > 0 Hz, got 0"
    )


# ---- accepted before, with a file written ---------------------------------------------------
@pytest.mark.parametrize(
    "argv, message",
    [
        (["tune", "--model", "model.npz", "--device", "cu5", "--max-steps", "0", "--out", "d.npz"],
         "--max-steps must be an integer in [1, 1000000], got 0"),
        (["tune", "--model", "model.npz", "--device", "cu5", "--quantile", "1.5", "--out", "d.npz"],
         "--quantile must be in (0, 1], got 1.5"),
        (["sweep", "scene.toml", "--vary", "protocol.periods=0", "--out", "sw"],
         "--vary protocol.periods must be an integer ≥ 1, got 0"),
        (["sweep", "scene.toml", "--vary", "controller.zeta_den=0.5,-1", "--out", "sw"],
         "--vary controller.zeta_den=-1: controller.zeta_den must be > 0"),
        (["sweep", "scene.toml", "--vary", "controller.k=0.5", "--chunk", "0", "--out", "sw"],
         "--chunk must be an integer in [1, 100000], got 0"),
        (["analyze", "--model", "model.npz", "--device", "cu5", "--k", "0", "--out", "a.json"],
         "--k must be > 0, got 0"),
        (["fit", "frf.npz", "--omega-c-hz", "0", "--out", "m.npz"], "--omega-c-hz must be > 0 Hz, got 0"),
        (["simulate", "--move", "100", "0", "0", "--out", "r.npz"], "--move must be three finite"),
        # ML takes optimistix solvers only; it used to fall back to lm without a word
        (["fit", "run.npz", "--method", "ml", "--solver", "jaxopt_lm", "--out", "m.npz"],
         "--solver jaxopt_lm is for --method nls only"),
    ],
)  # fmt: skip
def test_out_of_range_options_are_rejected_before_work(files, argv, message):
    assert_clean_error(argv, files[0], message)


# ---- misleading messages --------------------------------------------------------------------
def test_text_named_npz_says_which_file_and_what(files):
    d, _ = files
    (d / "text.npz").write_text("freq_hz,Z_H\n1,2\n")
    line = assert_clean_error(["fit", "text.npz", "--out", "m.npz"], d, "text.npz")
    assert "not a .npz (zip) archive" in line and "expected an FRF file" in line
    assert "pickle" not in line


def test_run_given_an_npz_says_expected_scene_toml(files):
    assert_clean_error(["run", "frf.npz"], files[0], "expected a scene TOML")
    d = files[0]
    (d / "bin.toml").write_bytes(b"\x00\xff\xfe binary")
    assert_clean_error(["run", "bin.toml"], d, "expected a scene TOML")


def test_robust_negative_max_samples(files):
    assert_clean_error(["robust", "--samples", "samples.npz", "--model", "model.npz",
                        "--max-samples", "-1"], files[0], "--max-samples must be an integer in [1, 10000000], got -1")  # fmt: skip


def test_simulate_negative_fs(files):
    line = assert_clean_error(
        ["simulate", "--fs", "-1000", "--out", "r.npz"], files[0], "--fs must be > 0 Hz, got -1000"
    )
    assert "Nyquist" not in line


def test_nan_positions_are_plain_ints(files, tmp_path):
    _, f = files
    d = dict(np.load(f["run"]))
    d["R_I"][1, 7, 2] = np.nan
    np.savez(tmp_path / "nan.npz", **d)
    line = assert_clean_error(["frf", "nan.npz", "--out", "x.npz"], tmp_path, "(1, 7, 2)")
    assert "np." not in line
    fr = dict(np.load(f["frf"]))
    fr["Z_T"][2, 0, 1] = np.nan
    np.savez(tmp_path / "nanfrf.npz", **fr)
    line = assert_clean_error(["fit", "nanfrf.npz", "--out", "m.npz"], tmp_path, "(2, 0, 1)")
    assert "np." not in line


# ---- every unreadable kind of file, at the reader ---------------------------------------------
def _unreadable(tmp_path, f):
    run = f["run"].read_bytes()
    (tmp_path / "empty.npz").write_bytes(b"")
    (tmp_path / "trunc.npz").write_bytes(run[: len(run) // 3])
    (tmp_path / "text.npz").write_text("hello\n")
    (tmp_path / "binary.npz").write_bytes(bytes(range(1, 200)))
    (tmp_path / "npy.npz").write_bytes(b"\x93NUMPY" + b"\x00" * 50)
    np.savez(tmp_path / "pickled.npz", fs_hz=np.array([{"a": 1}], dtype=object))
    (tmp_path / "v73.mat").write_bytes(
        b"MATLAB 7.3 MAT-file, Platform: GLNXA64" + b" " * 90 + b"\x89HDF\r\n"
    )
    (tmp_path / "text.mat").write_text("not a mat file\n")
    (tmp_path / "empty.mat").write_bytes(b"")
    with zipfile.ZipFile(tmp_path / "badmember.npz", "w") as z:
        z.writestr("fs_hz.npy", b"\x93NUMPY garbage")
    return {
        "empty.npz": "empty file", "trunc.npz": "unreadable", "text.npz": "text ('hello'",
        "binary.npz": "not a .npz", "npy.npz": "single-array .npy", "pickled.npz": "pickled",
        "v73.mat": "v7.3", "text.mat": "not a MAT-file", "empty.mat": "empty file",
        "badmember.npz": "unreadable",
    }  # fmt: skip


@pytest.mark.parametrize("loader", ["load_run", "load_frf", "load_model"])
def test_reader_names_file_and_expectation(files, tmp_path, recwarn, loader):
    import gc

    for name, frag in _unreadable(tmp_path, files[1]).items():
        with pytest.raises(hio.FileFormatError) as e:
            getattr(hio, loader)(tmp_path / name)
        msg = str(e.value)
        assert str(tmp_path / name) in msg and frag in msg and "expected" in msg, msg
        assert "\n" not in msg
    gc.collect()
    assert not [w for w in recwarn if issubclass(w.category, ResourceWarning)]


def test_samples_reader_names_file(files, tmp_path):
    from hapid.io import load_samples

    for name, frag in _unreadable(tmp_path, files[1]).items():
        if name.endswith(".npz"):
            with pytest.raises(ValueError, match=frag.replace("(", r"\(")):
                load_samples(tmp_path / name)


# ---- every option has a rule and a help text with its default -----------------------------
def _subcommands(parser):
    act = next(a for a in parser._actions if a.dest == "command")
    return act.choices


def test_every_option_of_every_subcommand_has_a_check():
    parser = build_parser()
    missing = []
    for cmd in _subcommands(parser):
        for dest, flag in options(parser, cmd):
            try:
                rule_for(cmd, dest)
            except KeyError:
                missing.append(f"{cmd} {flag}")
    assert not missing, f"options without a check in hapid/_cli_checks.py: {missing}"


def test_every_option_help_says_what_and_its_default():
    parser = build_parser()
    bad = []
    for cmd, sub in _subcommands(parser).items():
        for act in sub._actions:
            if act.dest == "help":
                continue
            name = f"{cmd} {max(act.option_strings, key=len) if act.option_strings else act.dest}"
            if not act.help:
                bad.append(f"{name}: no help")
                continue
            text = sub._get_formatter()._expand_help(act)
            has_default = (
                not any(act.default is x for x in (None, False, argparse.SUPPRESS))
                and not act.required
            )
            if has_default and "default" not in text.lower():
                bad.append(f"{name}: help does not state its default {act.default!r}")
    assert not bad, "\n".join(bad)


def test_argparse_errors_are_one_line_too(files):
    assert_clean_error(
        ["simulate", "--fs", "abc", "--out", "r.npz"], files[0], "invalid float value"
    )
    assert_clean_error(["fit", "frf.npz"], files[0], "required")


# ---- crashes the fuzz harness found ---------------------------------------------------------
def test_samples_with_nan_log_prob_are_rejected(files, tmp_path):
    d = dict(np.load(files[1]["samples"]))
    d["log_prob"][0] = np.nan
    np.savez(tmp_path / "s.npz", **d)
    (tmp_path / "model.npz").write_bytes(files[1]["model"].read_bytes())
    assert_clean_error(["robust", "--samples", "s.npz", "--model", "model.npz", "--out", "o.json"],
                       tmp_path, "log_prob has NaN or inf entries")  # fmt: skip


def test_design_with_nan_or_negative_frequency_names_the_file(tmp_path):
    from hapid.control import Compensator
    from hapid.tune import load_design, save_design

    save_design(tmp_path / "g.npz", Compensator.paper())
    d = dict(np.load(tmp_path / "g.npz"))
    for field, bad in (("k", np.nan), ("lag_poles", -1.0)):
        dd = dict(d, **{field: np.full(np.shape(d[field]), bad)})
        np.savez(tmp_path / "bad.npz", **dd)
        with pytest.raises(ValueError, match=f"bad.npz: {field}"):
            load_design(tmp_path / "bad.npz")


def test_console_script_error_is_one_stderr_line(tmp_path):
    """The real process (interpreter warning filters, exit code, stderr) for the first item
    of the issue: a 0-byte .npz."""
    import subprocess
    import sys

    (tmp_path / "empty.npz").write_bytes(b"")
    res = subprocess.run([sys.executable, "-W", "default", "-m", "hapid.cli", "frf", "empty.npz",
                          "--out", "o.npz"], cwd=tmp_path, capture_output=True, text=True)  # fmt: skip
    assert res.returncode == 2
    lines = res.stderr.splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("hapid: error: empty.npz: empty file (0 bytes); expected a run file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.npz"]


def test_posterior_on_a_fit_that_does_not_converge_names_max_steps(files):
    """The NLS fit a posterior is centred on stops at its step limit: one line naming
    --max-steps, no samples file (was an 'internal error, please report' with exit 1)."""
    d, _ = files
    line = assert_clean_error(
        ["posterior", "frf.npz", "--method", "laplace", "--max-steps", "1", "--out", "s.npz"],
        d,
        "the NLS fit the posterior is built around did not converge",
    )
    assert "--max-steps" in line and "max_steps" in line
