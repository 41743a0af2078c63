"""The declared PID's implementation read off the record (maglev_cosim.diagnosis.controller_form):
a record made by the independent emulator with another form of the same gains, declared as the
paper's PID, is replayed with the form that made it; the paper's form stays where it made the record."""

from __future__ import annotations

import json

import pytest

from maglev_cosim.diagnosis import diagnose
from maglev_cosim.diagnosis.controller_form import ADOPT_RATIO, identified, identify
from maglev_cosim.records.emulator_ivp import synth_record as ivp_record
from maglev_cosim.records.record import RecordError, read_record, write_record
from maglev_cosim.records.synth import draw_disturbance, synth_record


#: The records' length [s]: a staircase of 2 s holds a reference step or two.
DURATION = 2.0


@pytest.fixture(scope="module")
def ivp(tmp_path_factory):
    """A record of the independent emulator (seed 4, DURATION) with the PID's ``settings``, made once."""
    made: dict = {}

    def make(**settings):
        key = tuple(sorted(settings.items()))
        if key not in made:
            path = tmp_path_factory.mktemp("ivp") / "r.csv"
            made[key] = read_record(ivp_record(path, duration=DURATION, seed=4, settings=settings))
        return made[key]
    return make


@pytest.mark.parametrize("settings, derivative, tf", [
    ({"pid_derivative": "measurement"}, "measurement", 0.0),
    ({"pid_tf": 0.001}, "error", 0.001),
    ({"pid_derivative": "measurement", "pid_tf": 0.003}, "measurement", 0.003),
])
def test_a_pid_that_ran_in_another_form_is_identified(ivp, settings, derivative, tf):
    rec = ivp(**settings)
    assert rec.derivative == "error" and rec.tf == 0.0            # the record declares the gains alone
    form = identify(rec)
    assert form.adopted and form.derivative == derivative
    assert form.tf == pytest.approx(tf, rel=0.05, abs=2e-5)
    assert form.rms < ADOPT_RATIO * form.declared_rms
    again, same = identified(rec)
    assert (again.derivative, again.tf) == (form.derivative, form.tf)
    assert same.declared_rms == form.declared_rms
    assert f"{form.declared_rms:.3g} MU" in again.warnings[-1] and f"{form.rms:.3g} MU" in again.warnings[-1]


def test_the_declared_form_stays_where_it_made_the_record(ivp, tmp_path):
    for rec in (ivp(), read_record(synth_record(tmp_path / "rig.csv", duration=DURATION, seed=4))):
        form = identify(rec)
        assert not form.adopted and (form.derivative, form.tf) == ("error", 0.0)
        assert form.declared_rms < 5e-4          # the D/A's and the file's rounding (12 bits: 2.4e-4 MU a step)
        again, _ = identified(rec)
        assert again is rec


def test_a_record_declares_the_derivative_of_the_reading(ivp, tmp_path):
    rec = ivp(pid_derivative="measurement")
    path = write_record(tmp_path / "declared.csv", rec.t, rec.w, rec.u, rec.y, ts=rec.ts, kp=rec.kp, ki=rec.ki,
                        kd=rec.kd, u_min=rec.u_min, u_max=rec.u_max, derivative="measurement")
    declared = read_record(path)
    assert declared.derivative == "measurement" and declared.pid_kwargs()["derivative"] == "measurement"
    form = identify(declared)
    assert not form.adopted and form.declared_rms < 5e-4
    text = path.read_text().replace("# derivative: measurement", "# derivative: setpoint")
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    line = text.splitlines().index("# derivative: setpoint") + 1
    with pytest.raises(RecordError, match=f"bad.csv:{line}:15: derivative 'setpoint' is not one of error, measurement"):
        read_record(bad)


@pytest.mark.slow
def test_a_record_without_effects_made_by_another_pid_form_ends_no_effect(tmp_path):
    """Before the form was identified, this record (the disturbance draw of seed 7100, the PID's
    derivative of the reading alone) ended 'explained' by a current saturation: every replay kicked
    the output at each reference step where the rig had not."""
    path = ivp_record(tmp_path / "r.csv", seed=7100, disturbance=draw_disturbance(7100),
                      settings={"pid_derivative": "measurement"})
    d = diagnose(path, out=tmp_path / "out")
    assert d.verdict == "no effect" and d.selected == []
    assert any("the derivative of the reading alone" in w for w in d.warnings)
    doc = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert doc["verdict"] == "no effect" and any("replays that PID" in w for w in doc["warnings"])
    record_line = next(ln for ln in (tmp_path / "out" / "report.md").read_text().splitlines() if ln.startswith("Record:"))
    assert "derivative of the reading alone" in record_line
