"""Fuzz harness of the CLI's promise for bad input (issue 16): hypothesis generates malformed
run / FRF / model / samples / design / scene files and out-of-range option values for every
subcommand; every case must end in exit 2 with exactly one ``hapid: error:`` line, no
traceback, no warning and no output file (``helpers_cli.assert_clean_error``).

Every generated case is bad by construction (a required array dropped or corrupted, bytes that
are no file of the kind, a value outside the option's range), so a case the CLI accepts is a
bug. The extremes of every numeric option (huge, tiny, negative, NaN, infinite) are either
refused in one clean line or accepted by the checks (the slow profile then runs those to exit
0 or a clean exit 2). A fast profile runs in the default suite; the long one is ``slow`` and prints how many
cases it tried (``pytest -m slow -s tests/test_fuzz_cli.py``).
"""

from __future__ import annotations

import functools
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from helpers_cli import assert_clean_error, run_cli, write_valid_files
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

FAST = settings(max_examples=80, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))  # fmt: skip
LONG = settings(max_examples=3000, deadline=None, database=None,
                suppress_health_check=list(HealthCheck))  # fmt: skip

COUNT: dict[str, int] = {}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzzbase")
    write_valid_files(d)
    yield d
    total = sum(COUNT.values())
    parts = ", ".join(f"{k} {v}" for k, v in sorted(COUNT.items()))
    print(f"\nfuzz cases tried: {total} ({parts})")


def _workdir(base: Path) -> Path:
    d = Path(tempfile.mkdtemp(dir=base.parent))
    for f in base.iterdir():
        shutil.copy(f, d / f.name)
    return d


# ---- malformed files ----------------------------------------------------------------------------
REQUIRED = {
    "run": ("fs_hz", "period_samples", "freq_hz", "R_A", "R_I", "L"),
    "frf": ("freq_hz", "Z_H", "Z_T"),
    "model": ("M_H", "B_H", "K_H", "M_T", "B_T", "K_T"),
    "samples": ("samples", "log_prob", "n", "omega_ref", "z_ref"),
}
# commands that read each kind of file; "{f}" is the fuzzed file
READERS = {
    "run": [["frf", "{f}", "--out", "o.npz"]],
    "frf": [["fit", "{f}", "--method", "wls", "--out", "o.npz"],
            ["analyze", "--model", "model.npz", "--frf", "{f}", "--out", "o.json"],
            ["posterior", "{f}", "--method", "laplace", "--out", "o.npz"]],
    "model": [["analyze", "--model", "{f}", "--device", "tripod3", "--out", "o.json"],
              ["robust", "--samples", "samples.npz", "--model", "{f}", "--out", "o.json"],
              ["tune", "--model", "{f}", "--device", "tripod3", "--out", "o.npz"]],
    "samples": [["robust", "--samples", "{f}", "--model", "model.npz", "--out", "o.json"],
                ["predict", "--samples", "{f}", "--out", "o.npz"],
                ["tune", "--model", "model.npz", "--samples", "{f}", "--out", "o.npz"]],
    "design": [["analyze", "--model", "model.npz", "--device", "tripod3", "--design", "{f}",
                "--out", "o.json"]],
    "scene": [["run", "{f}", "--out", "o"],
              ["sweep", "{f}", "--vary", "controller.k=0.5", "--out", "o"],
              ["paper", "--scene", "{f}", "--out", "o"]],
}  # fmt: skip


def _bad_value(draw, a: np.ndarray) -> np.ndarray:
    """A replacement that breaks the contract of any required array ``a``."""
    kind = draw(
        st.sampled_from(["str", "object", "nan", "inf", "empty", "ndim", "shape", "complex"])
    )
    if kind == "complex" and a.dtype.kind == "c":
        kind = "nan"
    if kind == "str":
        return np.full(a.shape or (1,), draw(st.text(min_size=1, max_size=5)))
    if kind == "object":
        return np.array([None, {"x": 1}], dtype=object)
    if kind in ("nan", "inf"):
        b = np.array(a, dtype=np.complex128 if a.dtype.kind == "c" else np.float64, copy=True)
        if b.size == 0:
            return np.array([np.nan])
        idx = draw(st.integers(0, b.size - 1))
        b.reshape(-1)[idx] = np.nan if kind == "nan" else -np.inf
        return b
    if kind == "empty":
        return np.zeros((0,) * max(1, a.ndim))
    if kind == "ndim":
        return np.zeros(a.shape + (2, 2)) if a.ndim < 2 else np.zeros(a.shape[:1])
    if kind == "shape":
        return np.ones(tuple(s + draw(st.integers(1, 3)) for s in a.shape) or (2,))
    return a.astype(np.complex128) + 1j


@st.composite
def npz_defect(draw, kind: str, base: dict):
    d = dict(base)
    keys = REQUIRED[kind]
    how = draw(st.sampled_from(["drop", "value", "value", "value"]))
    k = draw(st.sampled_from(keys))
    if how == "drop":
        del d[k]
        return d
    d[k] = _bad_value(draw, np.asarray(d[k]))
    return d


@st.composite
def raw_bytes(draw, valid: bytes):
    how = draw(st.sampled_from(["empty", "binary", "text", "truncated", "zip-garbage", "npy"]))
    if how == "empty":
        return b""
    if how == "binary":
        return draw(st.binary(min_size=1, max_size=300))
    if how == "text":
        return draw(st.text(min_size=1, max_size=200)).encode()
    if how == "truncated":
        return valid[: draw(st.integers(1, len(valid) - 1))]
    if how == "npy":
        return b"\x93NUMPY" + draw(st.binary(max_size=100))
    import io

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr(draw(st.sampled_from(["fs_hz.npy", "Z_H.npy", "M_H.npy", "samples.npy"])),
                   draw(st.binary(max_size=200)))  # fmt: skip
    return buf.getvalue()


def _write_npz_dict(path: Path, d: dict) -> None:
    np.savez(path, **d)


JUNK = ["abc", "", "nan", "inf", "-inf", "1e999", "0x1", "1,2"]


@st.composite
def csv_defect(draw, text: str, kind: str):
    """A hapid CSV (run or FRF) with one defect that breaks its contract: a junk cell in a
    data row, a renamed required column, a row missing a cell, or (run) a broken header line."""
    lines = text.splitlines()
    head = 1 if kind == "run" else 0  # the run CSV's '# fs_hz=…' line
    how = draw(st.sampled_from(["cell", "cell", "column", "short", "meta"] if kind == "run"
                               else ["cell", "cell", "column", "short"]))  # fmt: skip
    if how == "meta":
        key = draw(st.sampled_from(["fs_hz", "period_samples", "freq_hz"]))
        meta = lines[0]
        start = meta.index(key + "=") + len(key) + 1
        end = meta.find(";", start)
        end = len(meta) if end < 0 else end
        lines[0] = meta[:start] + draw(st.sampled_from(["abc", "", "-1", "nan", "0"])) + meta[end:]
        return "\n".join(lines) + "\n"
    if how == "column":
        cols = lines[head].split(",")
        required = [i for i, c in enumerate(cols) if not c.startswith(("Z_H_std", "Z_T_std"))]
        i = draw(st.sampled_from(required))
        cols[i] = draw(st.sampled_from(["abc", "", cols[i] + "x"]))
        lines[head] = ",".join(cols)
        return "\n".join(lines) + "\n"
    r = draw(st.integers(head + 1, len(lines) - 1))
    cells = lines[r].split(",")
    i = draw(st.integers(0, len(cells) - 1))
    if how == "short":
        del cells[i]
    else:
        cells[i] = draw(st.sampled_from(JUNK))
    lines[r] = ",".join(cells)
    return "\n".join(lines) + "\n"


def _file_case(draw, base: Path, kind: str) -> tuple[str, bytes | dict]:
    """``(file name, content)``: bytes to write, or a dict to save as .npz/.mat."""
    valid_path = base / f"{kind}.npz"
    if kind in ("run", "frf") and draw(st.integers(0, 2)) == 0:
        text = (base / f"{kind}.csv").read_text()
        if draw(st.integers(0, 4)) == 0:
            return f"bad_{kind}.csv", draw(raw_bytes(text.encode()))
        return f"bad_{kind}.csv", draw(csv_defect(text, kind)).encode()
    if draw(st.booleans()):
        return f"bad_{kind}.npz", draw(raw_bytes(valid_path.read_bytes()))
    d = dict(np.load(valid_path))
    ext = draw(st.sampled_from([".npz", ".npz", ".mat"])) if kind != "samples" else ".npz"
    bad = draw(npz_defect(kind, d))
    return f"bad_{kind}{ext}", bad


def _materialize(d: Path, name: str, content) -> Path:
    p = d / name
    if isinstance(content, bytes):
        p.write_bytes(content)
    elif p.suffix == ".mat":
        from scipy.io import savemat

        savemat(p, {k: v for k, v in content.items() if np.asarray(v).dtype.kind != "O"})
    else:
        np.savez(p, **content)
    return p


# ---- scene files --------------------------------------------------------------------------------
SCENE_BAD = {
    "device.preset": st.sampled_from(['"nope"', "5", '""']),
    "device.move": st.sampled_from(["[1.0, 0, 0]", "[0, 0, 0, 0, 0, 0, 0]", '["a"]', "3", "[0, 0, nan]"]),
    "device.subject_seed": st.sampled_from(["-1", "1.5", '"x"', "true"]),
    "device.encoder": st.sampled_from(['"laser"', "1"]),
    "device.extra_modes": st.sampled_from(["1", '"yes"']),
    "protocol.freqs": st.sampled_from(["[]", "[0]", "[-1.0]", "[2.5]", "[600.0]", '"all"', "[nan]", "[1.0, 1.0]"]),
    "protocol.periods": st.integers(max_value=0).map(str) | st.sampled_from(["1.5", '"4"', "true"]),
    "protocol.transient": st.integers(max_value=-1).map(str),
    "protocol.amplitude": st.sampled_from(["0", "-0.3", "nan", "inf", '"big"']),
    "protocol.noise": st.sampled_from(["-1e-3", "nan", "-inf"]),
    "protocol.seed": st.sampled_from(["-1", "4294967296", "0.5"]),
    "protocol.synthesis": st.sampled_from(['"spectral"', "0"]),
    "protocol.pattern": st.sampled_from(['"random"', "[1, 2]"]),
    "fit.omega_c_hz": st.sampled_from(["0", "-7", "nan"]),
    "fit.f_max_hz": st.sampled_from(["0", "-40", "inf"]),
    "fit.weight": st.sampled_from(['"uniform"']),
    "fit.solver": st.sampled_from(['"newton"', "1"]),
    "controller.k": st.sampled_from(["0", "-0.85", "nan", "inf"]),
    "controller.notch_hz": st.sampled_from(["[0]", "[600.0]", "17", '["a"]']),
    "controller.lowpass_hz": st.sampled_from(["[-1.0]", "[500.0]"]),
    "controller.zeta_den": st.sampled_from(["0", "-0.5"]),
    "controller.lag_pole_hz": st.sampled_from(["0", "-1", "1000.0"]),
    "controller.siso_pm_deg": st.sampled_from(["0", "180", "-30"]),
    "analysis.f_min_hz": st.sampled_from(["0", "-1", "600.0"]),
    "analysis.n_freq": st.sampled_from(["0", "1", "10", "1.5"]),
    "analysis.band_hz": st.sampled_from(["0", "-30"]),
    "posterior.walkers": st.sampled_from(["-1", "1"]),
    "posterior.steps": st.sampled_from(["0", "-5"]),
    "posterior.samples": st.sampled_from(["0"]),
    "outputs.want": st.sampled_from(['["fig11"]', '"summary"', "[1]"]),
    "outputs.dir": st.sampled_from(['""', "3"]),
}  # fmt: skip


@st.composite
def bad_scene(draw):
    how = draw(st.sampled_from(["value", "value", "value", "unknown", "syntax", "bytes"]))
    if how == "bytes":
        return draw(st.binary(min_size=1, max_size=200).filter(lambda b: _not_utf8_or_bad_toml(b)))
    if how == "syntax":
        return draw(st.sampled_from([b"[device\npreset = 'cu5'", b"k = = 1", b"[a]\n[a]\n",
                                     b"device = 3", b"[controller]\nk = 0.5\nk = 0.6"]))  # fmt: skip
    if how == "unknown":
        sec = draw(st.sampled_from(["device", "protocol", "fit", "nosuch"]))
        return f"[{sec}]\n{draw(st.sampled_from(['zzz', 'K', 'preset_name']))} = 1\n".encode()
    key = draw(st.sampled_from(sorted(SCENE_BAD)))
    sec, k = key.split(".")
    return f"[{sec}]\n{k} = {draw(SCENE_BAD[key])}\n".encode()


def _not_utf8_or_bad_toml(b: bytes) -> bool:
    import tomllib

    try:
        tomllib.loads(b.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        return True
    return False


# ---- out-of-range options -----------------------------------------------------------------------
BASES = {
    "simulate": ["simulate", "--device", "tripod3", "--out", "o.npz"],
    "frf": ["frf", "run.npz", "--out", "o.npz"],
    "demo": ["demo", "--out", "o"],
    "fit": ["fit", "frf.npz", "--out", "o.npz"],
    "analyze": ["analyze", "--model", "model.npz", "--device", "tripod3", "--out", "o.json"],
    "posterior": ["posterior", "frf.npz", "--out", "o.npz"],
    "robust": ["robust", "--samples", "samples.npz", "--model", "model.npz", "--out", "o.json"],
    "sweep": ["sweep", "scene.toml", "--vary", "controller.k=0.5", "--out", "o"],
    "tune": ["tune", "--model", "model.npz", "--device", "tripod3", "--out", "o.npz"],
    "paper": ["paper", "--out", "o"],
    "run": ["run", "scene.toml", "--out", "o"],
    "predict": ["predict", "--samples", "samples.npz", "--out", "o.npz"],
    "plant": ["plant", "--device", "tripod3", "--out", "o.npz"],
}

NOT_POS = st.sampled_from(
    ["0", "-0", "-1e-9", "nan", "inf", "-inf", "-1000", "abc", ""]
) | st.floats(max_value=0, allow_nan=False).map(repr)
NEG = st.sampled_from(["-1e-9", "nan", "-inf", "inf", "x"]) | st.floats(max_value=-1e-300).map(repr)


def int_below(lo):
    return st.integers(max_value=lo - 1).map(str) | st.sampled_from(["1.5", "nan", "x", ""])


OPTION_BAD = {
    "--fs": NOT_POS, "--amplitude": NOT_POS, "--f-max-hz": NOT_POS, "--omega-c-hz": NOT_POS,
    "--band-hz": NOT_POS, "--k": NOT_POS, "--siso-gain": NOT_POS, "--rod-compliance": NOT_POS,
    "--noise": NEG, "--position-noise": NEG, "--encoder-res": NEG,
    "--cond-warn": st.sampled_from(["0.5", "0", "-1", "nan", "inf"]),
    "--period": int_below(2), "--periods": int_below(1), "--transient": int_below(0),
    "--max-steps": int_below(1), "--max-samples": int_below(1), "--chunk": int_below(1),
    "--n-train": int_below(1), "--n-holdout": int_below(1), "--steps": int_below(1),
    "--samples": int_below(1), "--subjects": int_below(0),
    "--walkers": st.sampled_from(["1", "-1", "-100", "x"]),
    "--nperseg": int_below(8), "--n-freq": int_below(2), "--delay": st.sampled_from(["-1", "1001", "0.5"]), "--fs-hz": NOT_POS, "--f-min-hz": NEG,
    "--seed": st.integers(max_value=-1).map(str) | st.integers(min_value=2**32).map(str),
    "--quantile": st.sampled_from(["0", "1.5", "-0.1", "nan", "1.0000001"]) | st.floats(min_value=1, exclude_min=True, allow_infinity=False).map(repr),
    "--gm-db": st.sampled_from(["-1", "nan", "61", "inf"]),
    "--pm-deg": st.sampled_from(["-1", "180", "200", "nan"]),
    "--freqs": st.sampled_from(["0", "-1,2", "abc", "1,,2", "nan", "2.5", "600", "1,1", "inf"]),
    "--device": st.text(min_size=1, max_size=8).filter(lambda s: s not in ("cu5", "tripod3", "hexapod6") and not s.startswith("-")),
    "--solver": st.sampled_from(["newton", "LM", "x"]),
    "--moves": st.sampled_from(["walk", "DE"]),
    "--vary": st.sampled_from(["controller.k=0", "controller.k=-1", "protocol.periods=0",
                               "protocol.periods=1.5", "device.dx=5", "protocol.noise=-1",
                               "fit.omega_c_hz=0", "nosuch.key=1", "controller.k", "controller.k=",
                               "controller.k=a", "protocol.seed=-3", "device.subject_seed=0.5",
                               "controller.zeta_den=-1", "analysis.n_freq=1", "device.dyaw=3",
                               "controller.notch_hz[1]=900", "analysis.f_min_hz=0",
                               "fit.max_steps=2.5", "controller.lowpass_hz[0]=-5"]),
    "--set": st.sampled_from(["controller.k=0", "nosuch.k=1", "protocol.periods=0", "k",
                              "device.preset=\"x\"", "fit.solver=\"newton\"", "analysis.n_freq=1"]),
    "--outputs": st.sampled_from(["fig11", "summary,nope", ""]),
}  # fmt: skip

MOVE_BAD = st.lists(st.sampled_from(["0", "0.1", "-0.05"]), min_size=2, max_size=2).flatmap(
    lambda ok: st.sampled_from(["100", "-0.3", "nan", "inf", "x"]).map(lambda b: [b, *ok])
)
OUT_BAD = st.sampled_from(["o.txt", "o", "o.npz.bak", "run.npz/o.npz"])


def _options_of(cmd):
    from hapid._cli_checks import options
    from hapid.cli import build_parser

    return [flag for _, flag in options(build_parser(), cmd) if flag.startswith("--")]


@st.composite
def bad_option(draw):
    cmd = draw(st.sampled_from(sorted(BASES)))
    argv = list(BASES[cmd])
    flags = [f for f in _options_of(cmd) if f in OPTION_BAD or f in ("--move", "--out")]
    flag = draw(st.sampled_from(sorted(flags)))
    if cmd in ("robust", "tune", "predict") and flag == "--samples":
        flag = "--n-train" if cmd == "tune" else "--max-samples"
    if flag == "--move":
        return argv + ["--move", *draw(MOVE_BAD)]
    if flag == "--out":
        i = argv.index("--out")
        if cmd in ("demo", "paper", "run", "sweep"):
            return argv[: i + 1] + ["run.npz"] + argv[i + 2 :]  # a file where a folder is meant
        return argv[: i + 1] + [draw(OUT_BAD)] + argv[i + 2 :]
    if flag == "--fs" and cmd == "analyze":  # --fs belongs with --frf
        argv = ["analyze", "--model", "model.npz", "--frf", "frf.npz", "--out", "o.json"]
    return argv + [f"{flag}={draw(OPTION_BAD[flag])}"]


# extremes of every numeric option: huge, tiny, negative, not-a-number, infinite
EXTREMES = st.sampled_from(["1e300", "-1e300", "1e13", "1e-300", "-1e-300", "5e-324", "nan", "inf",
                            "-inf", "-1", "0", "-0", "100000000", "9223372036854775808"])  # fmt: skip


@functools.cache
def _numeric_options(cmd) -> tuple[str, ...]:
    from hapid._cli_checks import options
    from hapid.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[cmd]
    flags = {flag for dest, flag in options(parser, cmd)}
    return tuple(sorted(max(a.option_strings, key=len) for a in sub._actions
                  if a.option_strings and a.type in (int, float)
                  and max(a.option_strings, key=len) in flags))  # fmt: skip


@st.composite
def extreme_option(draw):
    cmd = draw(st.sampled_from([c for c in sorted(BASES) if _numeric_options(c)]))
    flag = draw(st.sampled_from(_numeric_options(cmd)))
    v = draw(EXTREMES)
    if flag == "--move":
        return cmd, list(BASES[cmd]) + ["--move", v, "0", "0"]
    return cmd, list(BASES[cmd]) + [f"{flag}={v}"]


def _checks_accept(argv, cwd: Path) -> bool:
    """True when parsing and hapid._cli_checks accept ``argv`` in ``cwd`` (no work done)."""
    import contextlib
    import io
    import os

    from hapid._cli_checks import check_args
    from hapid.cli import build_parser

    parser = build_parser()
    old = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            check_args(parser, parser.parse_args([str(a) for a in argv]))
    except (SystemExit, ValueError):
        return False
    finally:
        os.chdir(old)
    return True


# ---- the properties -----------------------------------------------------------------------------
def _file_property(base, data):
    kind = data.draw(st.sampled_from(sorted(READERS)))
    d = _workdir(base)
    try:
        if kind == "scene":
            name, content = "bad.toml", data.draw(bad_scene())
        elif kind == "design":
            name, content = "bad_design.npz", _design_content(data.draw)
        else:
            name, content = _file_case(data.draw, base, kind)
        p = _materialize(d, name, content)
        argv = [a.replace("{f}", p.name) for a in data.draw(st.sampled_from(READERS[kind]))]
        COUNT[f"{kind} files"] = COUNT.get(f"{kind} files", 0) + 1
        assert_clean_error(argv, d)
    finally:
        shutil.rmtree(d, ignore_errors=True)


def _option_property(base, data):
    argv = data.draw(bad_option())
    d = _workdir(base)
    try:
        COUNT["options"] = COUNT.get("options", 0) + 1
        assert_clean_error(argv, d)
    finally:
        shutil.rmtree(d, ignore_errors=True)


def _extreme_property(base, data, run_accepted: bool):
    """An extreme value of a numeric option: refused in one clean line before any work, or
    accepted by the checks — then (``run_accepted``, the slow profile) the command runs to exit
    0 or a clean exit 2, never a traceback, an internal error or an abort."""
    cmd, argv = data.draw(extreme_option())
    d = _workdir(base)
    try:
        COUNT["option extremes"] = COUNT.get("option extremes", 0) + 1
        if not _checks_accept(argv, d):
            assert_clean_error(argv, d)
        elif run_accepted:
            rc, out, err, _, _ = run_cli(argv, d)
            assert rc in (0, 2), f"{argv}: exit {rc}\n{err}"
            assert "Traceback" not in out + err and "internal error" not in err, f"{argv}: {err}"
    finally:
        shutil.rmtree(d, ignore_errors=True)


def _design_content(draw):
    """A broken design file: bytes that are no .npz, or a valid one with a field dropped or
    replaced by strings, objects, complex, NaN or an empty array."""
    from hapid.tune._params import _FIELDS

    if draw(st.booleans()):
        return draw(raw_bytes(b"PK\x03\x04" + b"\x00" * 40))
    from hapid.control import Compensator

    g = Compensator.paper()
    d = {f: np.asarray(getattr(g, f), dtype=float) for f in _FIELDS}
    k = draw(st.sampled_from(sorted(_FIELDS)))
    if draw(st.booleans()):
        del d[k]
    else:
        a = np.atleast_1d(d[k]) if d[k].size else np.array([1.0])
        d[k] = draw(st.sampled_from([np.full(a.shape, "a"), np.array([None], dtype=object),
                                     a + 1j, np.full(a.shape, np.nan), -np.abs(a) - 1,
                                     np.full(a.shape, np.inf)]))  # fmt: skip
    return d


def _design_property(base, data):
    """``load_design`` (library level) raises ValueError naming the file for a broken design."""
    from hapid.tune import load_design

    d = _workdir(base)
    try:
        p = _materialize(d, "bad_design.npz", _design_content(data.draw))
        COUNT["design files (load_design)"] = COUNT.get("design files (load_design)", 0) + 1
        with pytest.raises(ValueError) as e:
            load_design(p)
        assert str(p) in str(e.value) and "\n" not in str(e.value)
    finally:
        shutil.rmtree(d, ignore_errors=True)


@FAST
@given(data=st.data())
def test_fuzz_files_fast(base, data):
    _file_property(base, data)


@FAST
@given(data=st.data())
def test_fuzz_options_fast(base, data):
    _option_property(base, data)


@settings(FAST, max_examples=40)
@given(data=st.data())
def test_fuzz_option_extremes_fast(base, data):
    _extreme_property(base, data, run_accepted=False)


@pytest.mark.slow
@settings(LONG, max_examples=300)
@given(data=st.data())
def test_fuzz_option_extremes_long(base, data):
    _extreme_property(base, data, run_accepted=True)


@FAST
@given(data=st.data())
def test_fuzz_design_files_fast(base, data):
    _design_property(base, data)


@pytest.mark.slow
@LONG
@given(data=st.data())
def test_fuzz_files_long(base, data):
    _file_property(base, data)


@pytest.mark.slow
@LONG
@given(data=st.data())
def test_fuzz_options_long(base, data):
    _option_property(base, data)


@pytest.mark.slow
@settings(LONG, max_examples=200)
@given(data=st.data())
def test_fuzz_design_files_long(base, data):
    _design_property(base, data)
