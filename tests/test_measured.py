"""Real rigs' records as published (maglev_cosim.measured), the unknown-controller replay and the
rig commands (maglev_cosim.rigfit). The shared records are read from $MAGLEV_REAL_DATA (default
../shared/data/real next to the clone); tests that need them are skipped where they are absent."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from maglev_cosim.measured import levitation_segments, read_inteco_mat, read_levitador, read_measured
from maglev_cosim.record import RecordError
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
def test_a_record_that_logged_the_filter_estimate_as_the_gap_is_flagged():
    m = read_inteco_mat(INTECO.parent / "results" / "step" / "PID_anti_windup - KF.mat")
    assert any("Kalman filter's gap" in w for w in m.warnings)
    m = read_inteco_mat(INTECO.parent / "results" / "step" / "MPC - KF.mat")
    assert not any("Kalman" in w for w in m.warnings)


@need_real
def test_unknown_controller_replay_beats_stays_put_on_an_mpc_record():
    """The MPC record (controller unknown to the tool): the published model, driven by the measured
    PWM duty, fits the coil current at over 80 % and predicts the gap 5 ms ahead better than
    'stays put' (measured: 85.2 % and skill +0.21 on the whole record)."""
    from maglev_cosim import rigfit

    rig = load_rig("inteco-mls2em")
    m = read_inteco_mat(INTECO.parent / "results" / "multisteps_stairs" / "MPC - KF.mat")
    (r,) = rigfit.prepare(rig, m)
    f = rigfit.figures(rig, r, rig.params)
    assert f["current"]["from_actuator"] > 80
    assert f["position"]["5 ms"]["skill_vs_stays_put"] > 0.05
    # the model is not merely the naive predictor: 50 ms ahead the open-loop instability wins
    assert f["position"]["50 ms"]["model"] < f["position"]["50 ms"]["stays_put"]


@pytest.mark.slow
@need_real
def test_calibrate_on_two_inteco_records_and_validate_on_a_third(tmp_path):
    """The cross-record command: one parameter set, per-record and per-signal fits, each record's own
    calibration (the spread), the fit on a record not used, JSON beside the report."""
    from maglev_cosim.cli import main

    a, b, c = (str(INTECO / "multisteps_stairs" / f"{n} - KF.mat") for n in ("LQR_tracking", "MPC", "LQI"))
    assert main(["calibrate", a, b, "--validate", c, "--rig", "inteco-mls2em", "--out", str(tmp_path)]) == 0
    d = json.loads((tmp_path / "rigfit.json").read_text())
    assert [len(r["segments"]) for r in d["records"]] == [1, 1] and len(d["validation"]) == 1
    seg = d["records"][0]["segments"][0]["after"]
    assert set(seg["position"]) == {"5 ms", "20 ms", "50 ms"} and seg["current"]["from_actuator"] > 80
    # the spread between records: each record's own coil and force gain
    assert set(d["spread"]) == {"k_e", "R_c", "k_DA", "u_0"} and d["calibration"]["cost_after"] < d["calibration"]["cost_before"]
    assert set(d["coil_drift"]) == {"R_c", "k_DA", "u_0"} and len(d["validation"][0]["own_coil"]) == 3
    assert d["verdict"] in ("no effect", "explained", "explained in part", "unexplained: mechanics",
                            "unexplained: actuator")
    # the calibration fits the mechanics' damping and force lag with the force law; the catalogue's
    # other effects were tried on held-out blocks, each with its gain per signal
    assert set(d["calibration"]["names"]) >= {"k_e", "z_e", "k_FV", "T_F"}
    ef = d["effects"]
    assert {c["effect"] for c in ef["candidates"] if c["round"] == 1} == {"delay"}
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
    from maglev_cosim.controllers import load_controller
    from maglev_cosim.loop import simulate
    from maglev_cosim.measured import Segment
    from maglev_cosim.rigfit import RigRecord

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
    """The catalogue's effects tried on a real rig's calibrated model (rigfit.effect_search), on
    records of the Inteco model: a 3 ms force lag is selected with its time constant, and a
    record without it selects nothing."""
    from maglev_cosim import rigfit

    rig = load_rig("inteco-mls2em")
    found = rigfit.effect_search(rig, [_inteco_record(rig, rig.params.replace(T_F=3e-3), 1)], rig.params)
    assert found["selected"] == ["force_lag"]
    assert found["parameters"]["T_F"] == pytest.approx(3e-3, rel=0.1)
    none = rigfit.effect_search(rig, [_inteco_record(rig, rig.params, 2)], rig.params)
    assert none["selected"] == [], none["candidates"]
