"""Real rigs' records as published (maglev_cosim.records.measured), the unknown-controller replay and the
rig commands (maglev_cosim.diagnosis.real_rig). The shared records are read from $MAGLEV_REAL_DATA (default
../shared/data/real next to the clone); tests that need them are skipped where they are absent."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from maglev_cosim.diagnosis import real_rig
from maglev_cosim.records.measured import levitation_segments, read_inteco_mat, read_levitador, read_measured
from maglev_cosim.records.record import RecordError
from maglev_cosim.rigs import load_rig

from real_data import REAL
INTECO = REAL / "inteco-mls2em" / "results"
LEVITADOR = REAL / "levitador-benchmark" / "data" / "datos_levitador.txt"
need_real = pytest.mark.skipif(not INTECO.is_dir(), reason="shared real records not present")


@need_real
def test_every_shared_inteco_record_reads_as_published():
    files = sorted(INTECO.glob("*/*.mat"))
    assert len(files) == 9
    for f in files:
        m = read_measured(f)
        assert m.fmt == "inteco-mat" and m.ts == pytest.approx(1e-3) and m.n in (10001, 15001)
        assert 0.005 < m.position.mean() < 0.022 and 0.3 < m.current.mean() < 2.0
        assert m.drive.min() >= -0.05 and m.drive.max() <= 1.0 and m.drive_unit == "1"
        assert {"velocity", "z_hat", "i_hat", "control"} <= set(m.extra)
        assert m.metadata["profile"] in ("step", "multisteps_stairs") and m.metadata["controller"] in f.stem


@need_real
def test_the_applied_duty_of_the_pid_records_is_row_12():
    """Rows 6 and 12 differ only in the PID records; row 12 (the applied duty) is the drive."""
    import scipy.io

    f = INTECO / "step" / "PID_anti_windup - KF.mat"
    raw = scipy.io.loadmat(f)["logouts"]
    m = read_inteco_mat(f)
    assert not np.allclose(raw[6], raw[12])
    assert np.array_equal(m.drive, raw[12]) and np.array_equal(m.extra["control"], raw[6])


def test_the_struct_layout_that_load_data_reads(tmp_path):
    import scipy.io

    n = 500
    t = np.arange(n) * 1e-3
    signals = np.zeros((1, 4), dtype=[("values", "O")])  # a MATLAB struct array signals(1..4).values
    for k, v in enumerate([(0.012 + 1e-4 * np.sin(t))[:, None], np.zeros((n, 1)),
                           np.c_[np.full(n, 1.0), np.full(n, 0.02)], np.c_[np.full(n, 0.4), np.zeros(n)]]):
        signals[0, k]["values"] = v
    s = {"time": t[:, None], "signals": signals}
    f = tmp_path / "exp.mat"
    scipy.io.savemat(f, {"MLS2EMExpData": s})
    m = read_inteco_mat(f)
    assert m.n == n and m.current[0] == 1.0 and m.drive[0] == 0.4 and m.reference is None


@pytest.mark.parametrize("content,where,what", [
    ("0.00 0.005 0.0196 0.827 0.04 9.86\n0.01 0.005 0.0196 0.827 0.27\n", ":2:29:", "5 fields, expected 6"),
    ("0.00 0.005 0.0196 0.827 0.04 9.86\n0.01 0.005 x 0.827 0.27 9.86\n", ":2:12:", "position: 'x' is not a number"),
    ("0.00 0.005 19.6 0.827 0.04 9.86\n0.01 0.005 19.7 0.827 0.27 9.86\n0.02 0.005 19.7 0.8 0.3 9.8\n", ":2:1:",
     "in mm rather than m"),
    ("0.00 0.005 0.0196 0.827 0.04 9.86\n0.01 0.005 0.0197 0.827 0.27 9.86\n0.05 0.005 0.0198 0.8 0.3 9.8\n"
     "0.06 0.005 0.0199 0.8 0.3 9.8\n", ":3:1:", "time is not uniform"),
])
def test_levitador_text_errors_name_line_and_column(tmp_path, content, where, what):
    f = tmp_path / "lev.txt"
    f.write_text(content)
    with pytest.raises(RecordError) as e:
        read_levitador(f)
    assert f"{f}{where}" in str(e.value) and what in str(e.value), str(e.value)


def test_non_uniform_time_is_resampled_on_request(tmp_path):
    t = np.r_[np.arange(0, 1, 0.01), np.arange(1.02, 2, 0.01)]
    rows = np.c_[t, np.full_like(t, 0.005), 0.015 + 1e-3 * np.sin(t), np.full_like(t, 0.8), 0.5 + 0.1 * t,
                 np.full_like(t, 5.0)]
    f = tmp_path / "lev.txt"
    np.savetxt(f, rows, fmt="%.6f")
    with pytest.raises(RecordError, match="not uniform"):
        read_levitador(f)
    m = read_levitador(f, resample=True)
    assert np.allclose(np.diff(m.t), 0.01) and m.warnings and "interpolated" in m.warnings[0]
    assert np.allclose(m.current, 0.5 + 0.1 * m.t, atol=1e-6)


def test_missing_and_foreign_files(tmp_path):
    with pytest.raises(RecordError, match="no such file"):
        read_measured(tmp_path / "none.mat")
    (tmp_path / "bad.mat").write_bytes(b"not matlab at all" * 10)
    with pytest.raises(RecordError, match="not a MATLAB .mat file"):
        read_measured(tmp_path / "bad.mat")
    import scipy.io

    scipy.io.savemat(tmp_path / "other.mat", {"data": np.zeros((3, 3))})
    with pytest.raises(RecordError, match=r"other.mat:0:0: no variable 'logouts' or 'MLS2EMExpData' \(found: data\)"):
        read_measured(tmp_path / "other.mat")


def test_segmentation_splits_at_planted_drops(tmp_path):
    """A synthetic gap record: lifted at 1 s, dropped onto the rest at 4 s, lifted at 5 s, dropped at 8 s."""
    ts = 0.01
    t = np.arange(0, 9, ts)
    rest = 0.0204
    z = np.full_like(t, rest)
    up = ((t >= 1) & (t < 4)) | ((t >= 5) & (t < 8))
    z[up] = 0.010 + 1e-4 * np.sin(7 * t[up])
    f = tmp_path / "lev.txt"
    np.savetxt(f, np.c_[t, np.full_like(t, 0.01), z, np.full_like(t, 0.8), np.full_like(t, 0.5),
                        np.full_like(t, 5.0)], fmt="%.4f")
    m = read_levitador(f)
    segs, excluded = levitation_segments(m, rest, margin=0.1)
    assert [(s.start, s.stop) for s in segs] == [(110, 390), (510, 790)]
    assert all(reason == "on a stop at 0.0204 m" for *_, reason in excluded)


def test_segmentation_cuts_the_magnet_and_a_coil_that_is_off(tmp_path):
    """Levitating 0-3 s, stuck to the magnet (gap 0) 3-4 s, levitating 4-7 s, coil off while the
    gap reads 1 mm 7-8 s (no ball under control), levitating 8-11 s. A 50 ms cut of the current
    inside a levitating stretch (a controller at its lower limit) is not a coil off."""
    ts = 0.01
    t = np.arange(0, 11, ts)
    z = 0.010 + 1e-4 * np.sin(7 * t)
    i = np.full_like(t, 0.8)
    z[(t >= 3) & (t < 4)] = 0.0
    off = (t >= 7) & (t < 8)
    z[off], i[off] = 0.001, 0.0156
    i[(t >= 1) & (t < 1.05)] = 0.0
    f = tmp_path / "lev.txt"
    np.savetxt(f, np.c_[t, np.full_like(t, 0.01), z, np.full_like(t, 0.8), i, np.full_like(t, 5.0)], fmt="%.4f")
    segs, excluded = levitation_segments(read_levitador(f), (0.0, 0.0204), margin=0.1)
    assert [(s.start, s.stop) for s in segs] == [(0, 290), (410, 690), (810, 1100)]
    assert [r for *_, r in excluded] == ["on a stop at 0 m", "coil off"]


@need_real
def test_levitador_record_has_its_drops_found():
    m = read_levitador(LEVITADOR)
    rig = load_rig("levitador")
    segs, excluded = levitation_segments(m, rig.stops)
    assert m.ts == pytest.approx(0.01) and len(segs) >= 3
    # the ball stuck to the magnet (gap 0) 4.34-5.58 s is not levitation, nor the coil off near 50 s
    assert not any(s.start <= k < s.stop for s in segs for k in (500, 5000))
    inside = np.concatenate([m.position[s.start:s.stop] for s in segs])
    assert np.mean(inside < 5e-4) < 0.01 and np.mean(np.abs(inside - rig.stops[1]) < 5e-4) < 0.01
    assert any("on a stop at 0 m" in r for *_, r in excluded) and any("coil off" in r for *_, r in excluded)


@need_real
def test_a_record_that_logged_the_filter_estimate_as_the_gap_is_flagged_and_not_calibrated_on():
    """Its segments are judged, not calibrated on (real_rig.information); a record with the sensor's
    reading, whose gap moves 3-20 um in 20 ms, is not refused for its quantisation (1.5 um)."""
    rig = load_rig("inteco-mls2em")
    m = read_inteco_mat(INTECO.parent / "results" / "step" / "PID_anti_windup - KF.mat")
    assert any("Kalman filter's gap" in w for w in m.warnings) and m.metadata["position_source"] == "estimate"
    segs = real_rig.prepare(rig, m)
    assert segs and all(s.estimate for s in segs)
    assert all(any("judged, not calibrated on" in w for w in real_rig.information(rig, s)) for s in segs)
    m = read_inteco_mat(INTECO.parent / "results" / "step" / "MPC - KF.mat")
    assert not any("Kalman" in w for w in m.warnings) and "position_source" not in m.metadata
    assert all(real_rig.information(rig, s) == [] for s in real_rig.prepare(rig, m))


@need_real
def test_unknown_controller_replay_beats_stays_put_on_an_mpc_record():
    """The MPC record (controller unknown to the tool): the published model, driven by the measured
    PWM duty, fits the coil current at over 80 % and predicts the gap 5 ms ahead better than
    'stays put' (measured: 85.2 % and skill +0.21 on the whole record)."""
    from maglev_cosim.diagnosis import real_rig

    rig = load_rig("inteco-mls2em")
    m = read_inteco_mat(INTECO.parent / "results" / "multisteps_stairs" / "MPC - KF.mat")
    (r,) = real_rig.prepare(rig, m)
    f = real_rig.figures(rig, r, rig.params)
    assert f.current["from_actuator"] > 80
    assert f.position["5 ms"].skill_vs_stays_put > 0.05
    # the model is not merely the naive predictor: 50 ms ahead, driven by the duty, the open-loop
    # instability wins (fit 67.2 % against 89.3 %); in closed loop with the controller identified
    # from the record's other blocks, which reads its reaction after the start, it does not (91.4 %)
    p50 = f.position["50 ms"]
    assert p50.model_measured_input < p50.stays_put < p50.model


@pytest.mark.slow
@need_real
def test_calibrate_on_two_inteco_records_and_validate_on_a_third(tmp_path):
    """The cross-record command: one parameter set, per-record and per-signal fits, each record's own
    calibration (the spread), the fit on a record not used, JSON beside the report."""
    from maglev_cosim.cli import main

    a, b, c = (str(INTECO / "multisteps_stairs" / f"{n} - KF.mat") for n in ("LQR_tracking", "MPC", "LQI"))
    assert main(["calibrate", a, b, "--validate", c, "--rig", "inteco-mls2em", "--out", str(tmp_path)]) == 0
    d = json.loads((tmp_path / "diagnosis.json").read_text())
    assert [len(r["segments"]) for r in d["records"]] == [1, 1] and len(d["validation"]) == 1
    seg = d["records"][0]["segments"][0]["after"]
    assert set(seg["position"]) == {"5 ms", "20 ms", "50 ms"} and seg["current"]["from_actuator"] > 80
    # the spread between records: each record's own coil and force gain
    assert set(d["spread"]) == {"k_e", "R_c", "k_DA", "u_0", "kappa_R", "force_gain_factor"} and d["calibration"]["cost_after"] < d["calibration"]["cost_before"]
    # each segment's own coil, and its own force gain where the force balance allows one
    assert {"R_c", "k_DA", "u_0", "kappa_R"} <= set(d["coil_drift"]) <= {"R_c", "k_DA", "u_0", "kappa_R", "k_e",
                                                                         "force_gain_factor"}
    assert len(d["validation"][0]["own_coil"]) in (5, 7)
    assert d["verdict"] in ("no effect", "explained", "explained in part", "unexplained: mechanics",
                            "unexplained: actuator")
    # the coil, then the force law with the disturbance model; the catalogue's effects were tried on
    # held-out blocks, each with its gain per signal (pairs only when no single one passes)
    # (the coil stage fits the drive's delay too, so the effect search does not try it again)
    assert d["coil_calibration"]["names"] == ["R_c", "k_DA", "u_0", "T_d"] and set(d["calibration"]["names"]) >= {"k_e", "z_e"}
    assert 0.5e-3 < d["parameters"]["T_d"] < 3e-3
    ef = d["effects"]
    singles = {c["effect"] for c in ef["candidates"] if c["round"] == 1 and "+" not in c["effect"]}
    # every effect the rig's drive and force law take (real_rig.rig_offer), but the delay the coil fits
    assert singles == {n for n, why in ef["offered"].items() if why is None} - {"delay"} and ef["skipped"] == ["delay"]
    # the model, the black box and the naive predictors side by side, per role and horizon
    assert set(d["comparison"]) == {"calibration", "validation"}
    assert set(d["comparison"]["validation"]["50 ms"]) >= {"model", "black_box", "constant_velocity"}
    assert all(set(c["held_out_gains"]) >= {"y", "i"} for c in ef["candidates"])
    assert set(ef["parameters"]) <= set(d["parameters"])
    assert 0.5 < d["validation"][0]["force_balance_calibrated"]["median"] < 1.5
    assert (tmp_path / "frequency_response.png").stat().st_size > 10000
    text = (tmp_path / "report.md").read_text()
    assert "Validation on records not used" in text and f"**Verdict: {d['verdict']}**" in text


@pytest.mark.slow
@need_real
def test_diagnose_a_levitador_record_says_it_carries_too_little_information(tmp_path):
    from maglev_cosim.cli import main

    assert main(["diagnose", str(LEVITADOR), "--rig", "levitador", "--out", str(tmp_path)]) == 0
    d = json.loads((tmp_path / "diagnosis.json").read_text())
    assert d["verdict"] == "too little information" and any("10 ms" in r for r in d["reasons"])
    assert (tmp_path / "report.md").read_text().startswith("# Rig levitador")


def test_a_real_record_without_its_rig_is_refused(tmp_path, capsys):
    from maglev_cosim.cli import main

    f = tmp_path / "x.mat"
    f.write_bytes(b"")
    assert main(["diagnose", str(f), "--out", str(tmp_path / "o")]) == 2
    assert "name its rig with --rig" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def _inteco_record(rig, params, seed: int):
    """8 s of the Inteco model under the shipped LQI, the gap stepping between 10 and 8 mm every
    second, read through 10 um of sensor noise and 5 mA of current noise."""
    from maglev_cosim.loop.controllers import load_controller
    from maglev_cosim.loop.simulate import simulate
    from maglev_cosim.records.measured import Segment
    from maglev_cosim.diagnosis.real_rig import RigRecord

    rng = np.random.default_rng(seed)
    n = 8000
    gap_ref = np.where((np.arange(n) * 1e-3 // 1.0) % 2 == 0, 0.010, 0.008)
    r = simulate(params, rig.reading(gap_ref), controller=load_controller("inteco-lqi").controller,
                 x_op=float(rig.to_x(0.010)))
    gap = rig.from_x(r["x"]) + rng.normal(0.0, 1e-5, n)
    return RigRecord(label=f"model {seed}", ts=1e-3, y=np.asarray(rig.reading(gap)), u=np.asarray(r["u"]),
                     current=np.asarray(r["i"]) + rng.normal(0.0, 5e-3, n), position=gap, segment=Segment(0, n))


@pytest.mark.slow
def test_effect_search_on_a_rig_finds_a_planted_force_lag_and_nothing_where_there_is_none():
    """The catalogue's effects tried on a real rig's calibrated model (real_rig.effect_search), on
    records of the Inteco model: a 3 ms force lag is selected with its time constant, and a
    record without it selects nothing."""
    from maglev_cosim.diagnosis import real_rig

    rig = load_rig("inteco-mls2em")
    found = real_rig.effect_search(rig, [_inteco_record(rig, rig.params.replace(T_F=3e-3), 1)], rig.params)
    assert found.selected == ["force_lag"]
    assert found.parameters["T_F"] == pytest.approx(3e-3, rel=0.1)
    none = real_rig.effect_search(rig, [_inteco_record(rig, rig.params, 2)], rig.params)
    assert none.selected == [], none.candidates


# ----------------------------------------------------------------------------- the levitador's sessions

SESSIONS = REAL / "levitador-benchmark" / "data" / "sesiones_kan_pinn"
SESSION_COLUMNS = "t y y_obs dy_obs i u yd"


def _session(path: Path, *, columns: str = SESSION_COLUMNS, n: int = 300, encoding: str = "latin-1",
             samples: int | None = None, ts_line: str = "0.01s", sep: str = "\t") -> dict[str, np.ndarray]:
    """A small file in the benchmark's second format: its Latin-1 header (accents in the title and
    keys), '# Columnas:' declaring the columns in the given order, tab-separated rows printed as
    the benchmark prints them. Returns the signals by column name."""
    t = np.arange(n) * 0.01
    sig = {"t": t, "y": np.round((0.005 + 5e-4 * np.sin(3 * t)) / 4.888e-5) * 4.888e-5,
           "y_obs": np.full(n, 0.005), "dy_obs": np.full(n, 0.01), "i": 0.4 + 0.01 * np.cos(3 * t),
           "u": 6.0 + 0.5 * np.sin(5 * t), "yd": np.where(t < 1.5, 0.005, 0.004), "mode": np.ones(n)}
    sig["gap"] = sig["y"]
    head = (f"# Dataset Levitador Magnético\n# Fecha: 2025-12-17T20:59:28.539829\n# Perfil: escalon\n"
            f"# Duración: {n * 0.01:.1f}s\n# Muestras: {n if samples is None else samples}\n# Ts: {ts_line}\n"
            f"# Parámetros modelo: k0=0.0704, k=0.0327, a=0.0052, R=2.72\n# Columnas: {columns}\n#\n")
    digits = {"t": 4, "i": 4, "u": 4, "mode": 0}
    rows = [sep.join(f"{sig[c][k]:.{digits.get(c, 6)}f}" for c in columns.split()) for k in range(n)]
    path.write_bytes((head + "\n".join(rows) + "\n").encode(encoding))
    return sig


def test_session_format_is_read_as_published(tmp_path):
    """Latin-1 header, tabs, 'Columnas:' declaring t y y_obs dy_obs i u yd: each signal in its place,
    the measured y (not the observer's y_obs) as the position, the encoding said."""
    f = tmp_path / "dataset_escalon_x.txt"
    sig = _session(f)
    with pytest.raises(UnicodeDecodeError):
        f.read_text(encoding="utf-8")
    m = read_measured(f)
    assert m.fmt == "columns" and m.n == 300 and m.ts == pytest.approx(0.01) and m.drive_unit == ""
    assert np.allclose(m.position, sig["y"], atol=1e-6) and not np.allclose(m.position, m.extra["y_obs"])
    assert np.allclose(m.current, sig["i"], atol=1e-4) and np.allclose(m.drive, sig["u"], atol=1e-4)
    assert np.allclose(m.reference, sig["yd"]) and set(m.extra) == {"y_obs", "dy_obs"}
    assert m.metadata["encoding"] == "latin-1" and m.metadata["Perfil"] == "escalon"
    assert m.metadata["Parámetros modelo"].startswith("k0=0.0704") and m.metadata["title"] == "Dataset Levitador Magnético"
    assert len(m.warnings) == 1 and "read as Latin-1" in m.warnings[0] and "only '#' header lines" in m.warnings[0]
    # the same content in UTF-8: no warning; and the format is told by the content, not the name
    g = tmp_path / "record.mat"
    _session(g, encoding="utf-8")
    from maglev_cosim.records.measured import sniff

    assert sniff(g) == "columns" and sniff(f) == "columns"
    m2 = read_measured(g)
    assert m2.metadata["encoding"] == "utf-8" and m2.warnings == [] and np.array_equal(m2.position, m.position)


def test_session_format_takes_any_declared_order_and_ignores_unknown_columns(tmp_path):
    f = tmp_path / "a.txt"
    sig = _session(f, columns="yd u mode i dy_obs y_obs y t")
    m = read_measured(f)
    assert np.allclose(m.position, sig["y"], atol=1e-6) and np.allclose(m.drive, sig["u"], atol=1e-4)
    assert np.allclose(m.t, sig["t"]) and np.allclose(m.reference, sig["yd"]) and "mode" not in m.extra
    assert any("unknown column(s) 'mode' (column 3) ignored" in w for w in m.warnings), m.warnings
    # a first line of names instead of '# Columnas:', blanks between the fields
    g = tmp_path / "b.txt"
    g.write_text("t y i u yd\n" + "".join(f"{k * 0.01:.2f} {0.005 + 1e-4 * (k % 3):.6f} 0.4 6.0 0.005\n"
                                          for k in range(200)))
    m = read_measured(g)
    assert m.fmt == "columns" and m.n == 200 and m.position[1] == pytest.approx(0.0051)
    # commas, given the '# columns:' line, and the declared names once more as a first line
    h = tmp_path / "c.csv"
    h.write_text("# columns: t, u, y\n# ts: 10 ms\nt,u,y\n" + "".join(f"{k * 0.01:.2f},6.0,{0.005 + 1e-4 * (k % 3):.6f}\n"
                                                                 for k in range(200)))
    m = read_measured(h)
    assert m.n == 200 and m.position[2] == pytest.approx(0.0052) and m.drive[0] == 6.0 and m.current is None


@pytest.mark.parametrize("columns, require, where, words", [
    ("t y_obs dy_obs i u yd", (), ":8:13:", "no column for the measured position [m] as 'y' or 'position' or 'gap'"),
    ("y i u yd", (), ":8:13:", "no column for the time [s] as 't' or 'time'"),
    ("t y y_obs dy_obs i yd", ("drive",), ":8:13:", "the actuator signal (coil voltage or duty) as 'u'"),
    ("t y i u y yd", (), ":8:21:", "column 'y' is declared twice"),
    ("t y gap i u yd", (), ":8:17:", "columns 'y' and 'gap' both hold the measured position"),
])
def test_session_format_refuses_missing_or_doubled_columns_naming_them(tmp_path, columns, require, where, words):
    f = tmp_path / "s.txt"
    _session(f, columns=columns)
    with pytest.raises(RecordError) as e:
        read_measured(f, require=require)
    assert f"{f}{where}" in str(e.value) and words in str(e.value), str(e.value)


def test_session_format_without_the_drive_reads_until_a_command_needs_it(tmp_path):
    f = tmp_path / "s.txt"
    _session(f, columns="t y i yd")
    m = read_measured(f)
    assert m.drive is None and m.current is not None
    f2 = tmp_path / "s2.txt"
    _session(f2, columns="t y u")
    m = read_measured(f2)
    assert m.current is None and m.reference is None and any("no coil current column" in w for w in m.warnings)


@pytest.mark.parametrize("edit, where, what", [
    (lambda rows: rows.replace("\t0.4", "\tx.4", 1), ":10:35:", "column 'i' (current): 'x.4100' is not a number"),
    (lambda rows: rows.replace("\n0.0100\t", "\n0.0100\t0.1\t", 1), ":11:", "8 fields"),
    (lambda rows: rows.replace("\t0.010000", "", 1), ":10:", "6 fields, the header (line 8) declares 7"),
    (lambda rows: rows.replace("# Ts: 0.01s", "# Ts: 0.001s"), ":6:7:", "sample time 0.001s disagrees with the time column"),
    (lambda rows: rows.replace("# Ts: 0.01s", "# Ts: fast"), ":6:7:", "'fast' is not a positive time"),
    (lambda rows: rows.replace("\n0.0200\t0.005", "\n0.0200\t5.005", 1), ":12:8:", "is it in mm rather than m"),
])
def test_session_format_errors_name_file_line_and_column(tmp_path, edit, where, what):
    f = tmp_path / "s.txt"
    _session(f)
    f.write_bytes(edit(f.read_bytes().decode("latin-1")).encode("latin-1"))
    with pytest.raises(RecordError) as e:
        read_measured(f)
    assert f"{f}{where}" in str(e.value) and what in str(e.value), str(e.value)


def test_session_format_counts_and_the_ce152_format_is_told_apart(tmp_path):
    f = tmp_path / "s.txt"
    _session(f, samples=2989)
    assert any("line 5 says 2989 samples, the file holds 300 data lines" in w for w in read_measured(f).warnings)
    from maglev_cosim.records.measured import sniff

    ce = tmp_path / "rec.txt"
    ce.write_text("# ts: 0.001\n# controller: pid\nt,w,u,y\n" + "".join(f"{k / 1000:.3f},0.4,0.5,0.4\n" for k in range(300)))
    assert sniff(ce) == "ce152"
    with pytest.raises(RecordError, match=r"rec.txt:3:1: a CE152-format record"):
        read_measured(ce)
    legacy = tmp_path / "legacy.csv"
    legacy.write_text("".join(f"{k / 100:.2f} 0.005 {0.0096 + 1e-4 * (k % 2):.4f} 0.827 0.04 9.86\n" for k in range(300)))
    assert sniff(legacy) == "levitador" and read_measured(legacy).fmt == "levitador"
    assert sniff(tmp_path / "none.txt") is None


need_session = pytest.mark.skipif(not sorted(SESSIONS.glob("dataset_*.txt")), reason="shared session records not present")


@need_session
def test_every_shared_session_reads_as_published():
    files = sorted(SESSIONS.glob("dataset_*.txt"))
    for f in files:
        m = read_measured(f)
        assert m.fmt == "columns" and m.ts == pytest.approx(0.01) and m.metadata["encoding"] in ("latin-1", "utf-8")
        assert m.metadata["columns"] == SESSION_COLUMNS and {"y_obs", "dy_obs"} <= set(m.extra)
        assert 0.0 <= m.position.min() and m.position.max() < 0.0215 and m.current.max() < 1.0
        assert 0.0 <= m.drive.min() and m.drive.max() <= 9.86 and 0.003 <= m.reference.min() <= m.reference.max() <= 0.007
        head = f.read_bytes().split(b"\n")
        assert int(m.metadata["Muestras"]) == m.n == sum(1 for ln in head if ln.strip() and not ln.startswith(b"#"))
    step = [f for f in files if "escalon" in f.name]
    if step:
        m = read_measured(step[0])
        assert m.n == 2989 and set(np.unique(m.reference)) == {0.004, 0.005}
        assert m.warnings and "Latin-1" in m.warnings[0]


@pytest.mark.slow
@need_session
def test_diagnose_the_shared_step_session_on_the_levitador_rig(tmp_path, capsys):
    """The second format through the levitador rig path, with the benchmark's cascade declared: the
    verdict's reasons are the file's (100 Hz, 0.05 mm steps), and the firmware cascade, started from
    rest, reproduces the recorded voltage (it cannot be checked loop by loop: no current reference)."""
    from maglev_cosim.cli import main

    (f,) = sorted(SESSIONS.glob("dataset_escalon_*.txt"))[:1]
    assert main(["diagnose", str(f), "--rig", "levitador", "--controller", "levitador-cascade",
                 "--out", str(tmp_path)]) == 0
    d = json.loads((tmp_path / "diagnosis.json").read_text())
    assert d["verdict"] == "too little information"
    assert any(r.startswith("sampled every 10 ms") for r in d["reasons"])
    (rec,) = d["records"]
    assert len(rec["segments"]) == 1 and rec["segments"][0]["after"]["samples"] > 2500
    cc = rec["controller_check"]
    assert cc["start"] == "rest" and cc["actuator_fit"] > 50 and cc["loops"] == {}
    assert any("reproduces the recorded actuator signal" in r for r in d["reasons"])
    assert "Latin-1" in capsys.readouterr().err


@need_real
def test_formats_are_told_by_content_not_by_name(tmp_path):
    import shutil

    from maglev_cosim.records.measured import sniff

    mat = tmp_path / "inteco_run.bin"          # a MATLAB level-4 file (no text header) under another name
    shutil.copy(INTECO / "step" / "MPC - KF.mat", mat)
    assert sniff(mat) == "inteco-mat" and read_measured(mat).fmt == "inteco-mat"
    txt = tmp_path / "levitador.mat"           # the levitador's first format under a MATLAB name
    shutil.copy(LEVITADOR, txt)
    assert sniff(txt) == "levitador" and read_measured(txt).n == read_levitador(LEVITADOR).n


def test_a_row_the_diagnosis_does_not_need_may_be_missing_but_not_one_it_needs(tmp_path):
    """A logouts file whose other coil's current is NaN is read without that row (a warning names
    it); one whose measured current is NaN is refused with the row and sample."""
    n = 400
    t = np.arange(n) * 1e-3
    L = np.zeros((14, n))
    L[0], L[1], L[2] = t, 0.009, 0.009 + 1e-4 * np.sin(40 * t)
    L[4], L[12] = 0.8 + 0.01 * np.cos(40 * t), 0.3 + 0.01 * np.cos(40 * t)
    bad = L.copy()
    bad[5, 17:] = np.nan                                   # the other coil's current (row 5)
    scipy.io.savemat(tmp_path / "other_coil.mat", {"logouts": bad})
    m = read_inteco_mat(tmp_path / "other_coil.mat")
    assert m.n == n and "current_2" not in m.extra and np.array_equal(m.current, L[4])
    assert any("read without row 5 (current_2) is not a finite number at sample 17" in w for w in m.warnings)
    bad = L.copy()
    bad[4, 30] = np.inf                                    # the measured current itself
    scipy.io.savemat(tmp_path / "current.mat", {"logouts": bad})
    with pytest.raises(RecordError, match=r"current.mat:0:0: logouts row 4 \(current\) is not a finite number at sample 30"):
        read_inteco_mat(tmp_path / "current.mat")
