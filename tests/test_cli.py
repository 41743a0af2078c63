"""The command line: files written, JSON keys, one-line errors and nothing written on bad input."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from fmpy.validation import validate_fmu


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "maglev_cosim.cli", *args], capture_output=True, text=True,
                          timeout=600)


@pytest.mark.slow   # the quick tier's 2-minute budget: fresh processes of the command line, 3-5 s
def test_step_writes_csv_png_json(tmp_path, fmu_path):
    r = cli("step", "--amplitude", "0.05", "--duration", "1.0", "--out", str(tmp_path), "--fmu", str(fmu_path))
    assert r.returncode == 0, r.stderr
    data = json.loads((tmp_path / "step.json").read_text())
    assert data["fmu_vs_reference"]["max_abs_dy"] <= 1e-6
    assert data["step_info"]["Overshoot"] > 0
    assert (tmp_path / "step.png").stat().st_size > 10000
    assert (tmp_path / "step.csv").read_text().count("\n") > 1000


@pytest.mark.slow   # the quick tier's 2-minute budget: fresh processes of the command line, 3-5 s
def test_linearize_json(tmp_path):
    js = tmp_path / "lin.json"
    r = cli("linearize", "--params", "eq18", "--current", "0.5612", "--json", str(js), "--plots", str(tmp_path))
    assert r.returncode == 0, r.stderr
    d = json.loads(js.read_text())
    assert {"A", "B", "C", "D", "poles"} <= set(d)
    assert d["B"][2][0] == pytest.approx(500.0)
    assert (tmp_path / "root_locus.png").exists() and (tmp_path / "closed_loop_bode.png").exists()


def test_bad_record_gives_one_line_and_writes_nothing(tmp_path):
    rec = tmp_path / "bad.csv"
    rec.write_text("# ts: 0.001\nt,w,u\n0.0,0.4,0.3\n")
    out = tmp_path / "out"
    r = cli("diagnose", str(rec), "--out", str(out))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{rec}:2:1:" in lines[0] and "y" in lines[0]
    assert not out.exists()


@pytest.mark.slow   # the quick tier's 2-minute budget: fresh processes of the command line, 3-5 s
def test_implausible_record_is_refused_before_anything_is_written(tmp_path):
    rec = tmp_path / "stuck.csv"                   # the ball lies on the floor while the reference asks 3 mm
    rec.write_text("t,w,u,y\n" + "".join(f"{k / 1000:.3f},0.4,1.0,{0.0025 + 1e-4 * (k % 2):.4f}\n" for k in range(3000)))
    out = tmp_path / "out"
    r = cli("diagnose", str(rec), "--out", str(out))
    assert r.returncode == 2 and not out.exists()
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{rec}:1:7: implausible record:" in lines[0] and "rests on a stop" in lines[0], r.stderr


@pytest.mark.parametrize("args, words", [
    (["synth", "--out", "x.csv", "--effect", "warp:k=1"], "unknown effect 'warp'"),
    (["synth", "--out", "x.csv", "--reference", "steps", "--period", "0.6"], "--period applies to a square or sine"),
    (["synth", "--out", "x.csv", "--reference", "square", "--period", "-1"], "--period"),
    (["synth", "--out", "x.csv", "--setting", "f_y=40"], "settings belong to the independent emulator"),
    (["synth", "--out", "x.csv", "--emulator", "ivp", "--setting", "f_y"], "--setting 'f_y': expected NAME=VALUE"),
    (["synth", "--out", "x.csv", "--emulator", "ivp", "--setting", "pid_tf=1ms"], "'1ms' is not a number"),
    (["step", "--out", "o", "--fmu", "/no/such.fmu"], "FMU not found"),
    (["step", "--out", "o", "--params", "nosuchset"], "invalid choice: 'nosuchset'"),
    (["step", "--out", "o", "--amplitude", "5"], "outside the readings of the travel [0.0025, 0.774] MU"),
    (["linearize", "--position", "0.01m"], "--position 10 mm lies outside the travel"),
    (["linearize", "--position", "10"], "--position 10 mm lies outside the travel between the stops [0, 6.3] mm"),
    (["linearize", "--position", "3.2 furlongs"], "is not a number with an optional unit"),
    (["linearize", "--current", "5"], "--current 5 A lies outside the amplifier's range (0, i_max = 1.5] A"),
    (["identify", "/no/such.csv"], "file not found"),
    (["step", "--out", "o", "--duration", "-1"], "must be a positive finite number"),
    (["frobnicate"], "invalid choice"),
])
def test_errors_are_one_line(tmp_path, monkeypatch, capsys, args, words):
    """In-process (one interpreter start per case cost 3 s): main's exit status and stderr; the
    process-level behaviour (exit status, nothing written) is test_errors_write_nothing's."""
    from maglev_cosim.cli import main

    monkeypatch.chdir(tmp_path)
    try:
        rc = main(list(args))
    except SystemExit as exc:          # argparse's own errors
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and "Traceback" not in err, err


def test_errors_write_nothing(tmp_path):
    r = subprocess.run([sys.executable, "-m", "maglev_cosim", "step", "--amplitude", "5", "--out", "o"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 2 and list(tmp_path.iterdir()) == []


@pytest.mark.slow   # the quick tier's 2-minute budget: fresh processes of the command line, 3-5 s
def test_positions_take_mm_or_a_unit_and_linearize_writes_nothing_unasked(tmp_path, monkeypatch, capsys):
    from maglev_cosim.cli import main

    r = subprocess.run([sys.executable, "-m", "maglev_cosim", "linearize", "--position", "3.2"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    outs = [r.stdout]
    for pos in ("3.2mm", "0.0032m", "3200um"):   # the same parser in-process: one interpreter start is enough
        monkeypatch.chdir(tmp_path)
        assert main(["linearize", "--position", pos]) == 0
        outs.append(capsys.readouterr().out)
    assert len(set(outs)) == 1 and "x = 3.2 mm" in outs[0] and "bandwidth_hz 29.6" in outs[0]
    assert list(tmp_path.iterdir()) == []           # no ./linearize/ unless --plots is given


@pytest.mark.slow   # the quick tier's 2-minute budget: five fresh processes, 4-5 s
def test_help_version_and_module_entry_point(capsys):
    r = subprocess.run([sys.executable, "-m", "maglev_cosim", "--version"], capture_output=True, text=True, timeout=60)
    from maglev_cosim import __version__

    assert r.returncode == 0 and r.stdout.strip() == f"maglev-cosim {__version__}"
    r = subprocess.run([sys.executable, "-m", "maglev_cosim", "--help"], capture_output=True, text=True, timeout=60)
    assert "examples:" in r.stdout and "periodic_disturbance: A_d [V], f_d [Hz], phi_d [rad]" in r.stdout
    from maglev_cosim.cli import main

    for command in ("step", "linearize", "bench", "diagnose", "identify", "synth", "demo"):
        with pytest.raises(SystemExit) as exit_:   # in-process: the entry point was started above
            main([command, "--help"])
        assert exit_.value.code == 0
        options = [ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("--")]
        assert options, command
        # every option has a help text: a line with the option and its description, or a wrapped one
        for ln in options:
            assert len(ln.split()) > 1 or ln.strip() in ("--no-noise", "--no-diagnose", "--no-simplex"), (command, ln)


@pytest.mark.slow
def test_synth_then_diagnose_writes_the_report_and_a_valid_calibrated_fmu(tmp_path, fmu_path):
    rec = tmp_path / "rec.csv"
    r = cli("synth", "--out", str(rec), "--effect", "delay:T_d=0.003", "--reference", "square", "--seed", "2")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "diag"
    r = cli("diagnose", str(rec), "--out", str(out), "--fmu", str(fmu_path))
    assert r.returncode == 0, r.stderr
    assert "round 1" in r.stderr                 # progress while it works
    d = json.loads((out / "diagnosis.json").read_text())
    assert {"record", "before", "after", "selected", "parameters", "candidates"} <= set(d)
    assert d["record_warnings"] == [] and d["verdict"] == "explained" and isinstance(d["warnings"], list)
    for key in ("fit", "fit_before"):
        assert set(d[key]) == {"free_run", "prediction"} and d[key]["prediction"]["horizon_s"] == 0.02
        assert all(0 < d[key][m][s] <= 100 for m in ("free_run", "prediction") for s in ("y", "u"))
    assert d["fit"]["free_run"]["u"] > d["fit_before"]["free_run"]["u"]
    assert d["selected"] == ["delay"] and d["parameters"]["T_d"] == pytest.approx(0.003, rel=0.1)
    for c in d["candidates"]:
        assert {"effect", "parameters", "rms_y", "rms_u", "accepted"} <= set(c)
    report = (out / "report.md").read_text()
    assert report.splitlines()[2].startswith("**Verdict: explained.**")
    for png in ("measured_vs_simulated.png", "residual.png", "spectrum.png", "zoom.png", "resid.png"):
        assert png in report and (out / png).stat().st_size > 10000
    assert "Criterion" in report and "| T_d | " in report and "| s |" in report   # units in the tables
    html = (out / "report.html").read_text()
    assert html.count('src="data:image/png;base64,') == 5 and "<table>" in html
    assert not re.search(r'src="[^"]*\.png"', html)          # nothing left to fetch beside the page
    fmu = out / "maglev_calibrated.fmu"
    assert validate_fmu(str(fmu)) == []
    from fmpy import read_model_description

    md = {v.name: v for v in read_model_description(str(fmu)).modelVariables}
    assert float(md["T_d"].start) == pytest.approx(d["parameters"]["T_d"])
    assert float(md["T_a"].start) == 0.0
    # provenance: its own GUID and name, a description naming the record, the date and the effect,
    # the report as its documentation, and the calibration with the record's hash
    import hashlib
    import zipfile

    from maglev_cosim.plant.model_description import GUID

    desc = read_model_description(str(fmu))
    with zipfile.ZipFile(fmu) as z:
        cal = json.loads(z.read("resources/calibration.json"))
        assert z.read("documentation/index.html") == html.encode()
        assert {"report.md", "diagnosis.json", "zoom.png"} <= {n.split("/", 1)[1] for n in z.namelist()
                                                              if n.startswith("documentation/")}
    assert cal["record"]["sha256"] == hashlib.sha256(rec.read_bytes()).hexdigest()
    assert desc.guid != GUID and desc.guid == cal["guid"] and desc.modelName == cal["model_name"]
    assert "rec.csv" in desc.modelName and "rec.csv" in desc.description and cal["date"] in desc.description
    assert "delay (T_d = " in desc.description and cal["effects"] == ["delay"]
    assert cal["parameters"]["T_d"]["value"] == d["parameters"]["T_d"]
    assert cal["parameters"]["T_d"]["sigma"] == pytest.approx(d["uncertainties"]["T_d"])
    assert cal["fit"]["verdict_fit"] == d["fit"]
    from fmpy import simulate_fmu

    r = simulate_fmu(str(fmu), stop_time=0.01)     # fmpy instantiates it with the issued GUID
    assert len(r) > 1


@pytest.mark.slow
def test_identify_prints_the_papers_values(tmp_path):
    rec = tmp_path / "rec.csv"
    assert cli("synth", "--out", str(rec), "--reference", "square", "--seed", "4").returncode == 0
    js = tmp_path / "id.json"
    r = cli("identify", str(rec), "--json", str(js))
    assert r.returncode == 0, r.stderr
    assert "least_squares" in r.stdout and "0.0083" in r.stdout
    d = json.loads(js.read_text())
    assert d["least_squares"]["x_0"] == pytest.approx(0.0083, rel=0.02)
    assert d["least_squares"]["k_c"] == pytest.approx(6.9e-6, rel=0.03)
    assert d["simplex"]["k_FV"] == pytest.approx(0.03, rel=0.3)


@pytest.mark.slow
def test_bench_prints_tables(fmu_path, tmp_path):
    js = tmp_path / "bench.json"
    r = cli("bench", "--duration", "1", "--no-diagnose", "--fmu", str(fmu_path), "--json", str(js))
    assert r.returncode == 0, r.stderr
    d = json.loads(js.read_text())
    assert d["closed_loop"]["steps"] == 1000 and d["closed_loop"]["fast_us_per_step"] > 0
    assert "per step [us]" in r.stdout and "Communication-step independence" in r.stdout
    assert "cffi fast path" in r.stdout


@pytest.mark.slow
def test_demo_runs_every_stage_and_prints_the_truth_next_to_the_estimate(tmp_path):
    """The README's main job (`scripts/demo.sh` runs this command)."""
    r = cli("demo", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "planted truth" in r.stdout and "T_d" in r.stdout
    for f in ("step/step.png", "linearize.json", "linearize/root_locus.png", "diagnosis/report.html",
              "diagnosis/diagnosis.json", "record_undeclared_effect.csv"):
        assert (tmp_path / f).exists(), f
    assert json.loads((tmp_path / "diagnosis" / "diagnosis.json").read_text())["verdict"] == "explained"


def _ce152_csv(path: Path) -> Path:
    path.write_text("# ts: 0.001\n# controller: pid\nt,w,u,y\n"
                    + "".join(f"{k / 1000:.3f},0.4,0.5,{0.4 + 1e-3 * (k % 3):.4f}\n" for k in range(1500)))
    return path


def _levitador_session(path: Path, columns: str = "t y y_obs dy_obs i u yd") -> Path:
    """A small record in the levitador benchmark's second format (Latin-1 header, tabs)."""
    sig = {"t": lambda k: f"{k * 0.01:.4f}", "y": lambda k: f"{0.005 + 4.888e-5 * (k % 5):.6f}",
           "y_obs": lambda k: "0.005000", "dy_obs": lambda k: "0.000000", "i": lambda k: "0.4000",
           "u": lambda k: f"{6 + 0.1 * (k % 7):.4f}", "yd": lambda k: "0.005000"}
    head = f"# Dataset Levitador Magnético\n# Ts: 0.01s\n# Columnas: {columns}\n#\n"
    body = "".join("\t".join(sig[c](k) for c in columns.split()) + "\n" for k in range(400))
    path.write_bytes((head + body).encode("latin-1"))
    return path


@pytest.mark.parametrize("make, args, words", [
    # a CE152 record given a real rig: said so, with the file, instead of "1 fields, expected 6"
    (_ce152_csv, ["diagnose", "{f}", "--rig", "inteco-mls2em", "--out", "o"],
     "{f} is a CE152-format record (docs/record-format.md: '# key: value' metadata, then the header t,w,u,y in "
     "machine units), not a record of a real rig: --rig inteco-mls2em does not fit it; diagnose it without --rig"),
    (_ce152_csv, ["calibrate", "{f}", "--rig", "levitador", "--out", "o"], "{f} is a CE152-format record"),
    # a real rig's record without --rig, or with the CE152's: which --rig it likely needs
    (_levitador_session, ["diagnose", "{f}", "--out", "o"],
     "{f} is a text record that declares its columns, a real rig's record: name its rig with --rig (inteco-mls2em, "
     "levitador, or a rig file, docs/rigs.md); likely --rig levitador (its 10 ms sample time and its travel 0-20.4 "
     "mm fit the record)"),
    (_levitador_session, ["diagnose", "{f}", "--rig", "ce152", "--out", "o"],
     "not a CE152-format record: --rig ce152 does not fit it; likely --rig levitador"),
    # a column the command needs, missing: refused before anything runs, naming the file and the line
    (lambda p: _levitador_session(p, "t y i yd"), ["diagnose", "{f}", "--rig", "levitador", "--out", "o"],
     "{f}:3:13: the header declares no column for the actuator signal (coil voltage or duty) as 'u' or 'drive'"),
    (lambda p: _levitador_session(p, "t y i u"),
     ["diagnose", "{f}", "--rig", "levitador", "--controller", "levitador-cascade", "--out", "o"],
     "no column for the position reference [m] as 'yd' or 'reference' (this command needs the position reference"),
])
def test_a_record_that_does_not_fit_the_rig_flag_is_refused_in_one_line(tmp_path, monkeypatch, capsys, make, args, words):
    from maglev_cosim.cli import main

    monkeypatch.chdir(tmp_path)
    f = make(tmp_path / "rec.txt")
    assert main([a.format(f=f) for a in args]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and words.format(f=f) in lines[0] and "Traceback" not in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.skipif(not (Path(__file__).resolve().parent / "real_data.py").exists(), reason="no real_data helper")
def test_the_shared_inteco_record_without_rig_names_its_likely_rig(monkeypatch, capsys, tmp_path):
    from real_data import REAL

    f = REAL / "inteco-mls2em" / "results" / "step" / "MPC - KF.mat"
    if not f.exists():
        pytest.skip("shared real records not present")
    from maglev_cosim.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["diagnose", str(f), "--out", "o"]) == 2
    err = capsys.readouterr().err.strip()
    assert "is an Inteco MATLAB results file, a real rig's record" in err and "likely --rig inteco-mls2em" in err
