"""The real-rig effect search's candidates (maglev_cosim.diagnosis.real_rig.rig_candidates): derived from the
diagnosis's catalogue (maglev_cosim.diagnosis.effects.CATALOGUE) by the rig's coil drive and force law, with
the catalogue's ranges and start grids, and the values each entry computes from the records."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglev_cosim.diagnosis import real_rig
from maglev_cosim.diagnosis.effects import CATALOGUE, DRIVES, FORCE_LAWS, REFERENCE_K_X, force_law
from maglev_cosim.records.measured import Segment
from maglev_cosim.rigs import load_rig

from real_data import REAL

INTECO = REAL / "inteco-mls2em" / "results"
need_real = pytest.mark.skipif(not INTECO.is_dir(), reason="shared real records not present")


def _record(rig, gap: np.ndarray) -> real_rig.RigRecord:
    """A segment holding the gaps ``gap`` [m] (1 kHz; input and current constant): what the candidates
    read of the records (their positions and length)."""
    n = len(gap)
    return real_rig.RigRecord(label="test", ts=1e-3, y=np.asarray(rig.reading(gap)), u=np.full(n, 0.5),
                              current=np.full(n, 1.0), position=gap, segment=Segment(0, n))


def _offered(name: str) -> set[str]:
    rig = load_rig(name)
    offer = real_rig.rig_offer(rig.drive, force_law(real_rig._values_of(rig.params)))
    return {n for n, why in offer.items() if why is None}


def test_every_entry_declares_its_drives_and_force_laws_with_a_reason_for_each_one_left_out():
    for eff in CATALOGUE.values():
        assert set(eff.drives) <= set(DRIVES) and set(eff.force_laws) <= set(FORCE_LAWS)
        assert set(eff.not_for) == (set(DRIVES) - set(eff.drives)) | (set(FORCE_LAWS) - set(eff.force_laws))
        assert all(len(why) > 20 for why in eff.not_for.values())
    # the current amplifier's own effects are those a voltage drive does not take
    assert {n for n, e in CATALOGUE.items() if "voltage" not in e.drives} == {"amplifier_lag", "current_saturation",
                                                                             "amplifier_dead_zone"}


def test_a_voltage_drive_rig_is_offered_the_catalogue_but_the_amplifiers_effects():
    """The Inteco (voltage drive, exponential law): every entry that means something for its drive and
    law, the damping beside them; not the current amplifier's lag, limit and dead zone, nor the inverse
    square's exponent; the entries the real-rig search leaves out (RIG_LEFT_OUT) each with its reason."""
    rig = load_rig("inteco-mls2em")
    offer = real_rig.rig_offer(rig.drive, force_law(real_rig._values_of(rig.params)))
    assert rig.drive == "voltage"
    for name in ("amplifier_lag", "current_saturation", "amplifier_dead_zone"):
        assert offer[name].startswith("not for a voltage drive: ")
    assert offer["force_exponent"].startswith("not for the exponential force law: ")
    applicable = {n for n, e in CATALOGUE.items() if e.applies("voltage", "exponential") is None}
    assert "coulomb_friction" in applicable and "sensor_drift" in applicable
    assert {n for n, why in offer.items() if why is None} == (applicable - set(real_rig.RIG_LEFT_OUT)) | {"damping"}
    assert all(offer[n] == why for n, why in real_rig.RIG_LEFT_OUT.items())
    # the candidates: the offer but what the calibration fits, each with the catalogue's ranges and grid
    cands = real_rig.rig_candidates(rig, [], rig.params, skip=("k_e", "z_e", "T_d"))
    assert {c.name for c in cands} == {n for n, why in offer.items() if why is None} - {"delay"}
    values = real_rig._values_of(rig.params)
    for c in cands:
        if c.name in CATALOGUE:
            eff = CATALOGUE[c.name]
            assert c.coords == eff.rig_coords(values) and c.location == eff.location
            assert [list(z) for z in c.grid] == eff.rig_grid(values, np.array([values["x_start"]]))
            assert all(k.lo <= v <= k.hi for z in c.grid for k, v in zip(c.coords, z))
    # its record holds the position (k_x = 1 V/m): the ranges on the sensor's voltage follow its gain
    drift = next(c for c in cands if c.name == "sensor_drift")
    assert drift.coords[0].hi == pytest.approx(CATALOGUE["sensor_drift"].coords[0].hi * values["k_x"] / REFERENCE_K_X)
    assert values["k_x"] == 1.0 and REFERENCE_K_X > 100


def test_a_current_drive_rig_is_offered_the_current_drive_entries():
    """The CE152 (current amplifier, inverse square): the amplifier's lag, limit and dead zone, and the
    force exponent, besides the entries every drive takes."""
    offered = _offered("ce152")
    assert {"amplifier_lag", "current_saturation", "amplifier_dead_zone", "force_exponent", "force_lag",
            "sensor_lag", "sensor_drift", "force_gain_drift", "damping"} <= offered
    assert offered == {n for n, e in CATALOGUE.items() if e.applies("current", "inverse-square") is None} \
        - set(real_rig.RIG_LEFT_OUT) | {"damping"}
    # a voltage drive with Eq. 8's law (the levitador) takes the exponent but not the amplifier's effects
    lev = _offered("levitador")
    assert "force_exponent" in lev and not {"amplifier_lag", "current_saturation", "amplifier_dead_zone"} & lev


def test_entries_get_the_values_they_compute_from_the_records():
    """The force exponent's pivot x_n at the records' mean position; a sensor bend that keeps the reading
    and its slope there; a force gain drift that keeps the gain at the records' middle."""
    lev = load_rig("levitador")
    gap = 0.008 + 0.001 * np.sin(np.linspace(0, 20, 3000))
    cands = {c.name: c for c in real_rig.rig_candidates(lev, [_record(lev, gap)], lev.params)}
    vals = cands["force_exponent"].to_values([2.5])
    assert vals["n_F"] == 2.5 and vals["x_n"] == pytest.approx(float(np.mean(lev.to_x(gap))))

    rig = load_rig("inteco-mls2em")
    r = _record(rig, gap)
    cands = {c.name: c for c in real_rig.rig_candidates(rig, [r], rig.params)}
    p = rig.params.replace(**cands["sensor_nonlinearity"].to_values([-20.0]))
    x = np.asarray(rig.to_x(gap))
    xm = float(np.mean(x))

    def volts(q, at):
        return q.k_x * at + q.y_0 + q.k_x2 * at * (at - q.x_cal)

    assert p.k_x2 == -20.0 and volts(p, xm) == pytest.approx(volts(rig.params, xm), abs=1e-12)
    slope = (volts(p, xm + 1e-6) - volts(p, xm - 1e-6)) / 2e-6
    assert slope == pytest.approx(rig.params.k_x, rel=1e-6)
    drift = cands["force_gain_drift"].to_values([0.01])
    assert drift["k_e"] * (1 + 0.01 * 1.5) == pytest.approx(rig.params.k_e)     # 3 s: the middle at 1.5 s


@pytest.mark.slow
@need_real
def test_a_real_records_diagnosis_lists_every_candidate_with_its_values(tmp_path):
    """diagnose on one Inteco record: its effect search tried every effect its drive takes but the delay
    (the coil's calibration fits it), each named in the JSON's candidates with its values."""
    from maglev_cosim.cli import main

    f = INTECO / "step" / "MPC - KF.mat"
    assert main(["diagnose", str(f), "--rig", "inteco-mls2em", "--out", str(tmp_path)]) == 0
    ef = json.loads((tmp_path / "diagnosis.json").read_text())["effects"]
    offered = {n for n, why in ef["offered"].items() if why is None}
    assert offered >= {"force_lag", "sensor_lag", "sensor_nonlinearity", "sensor_drift", "force_gain_drift", "damping"}
    first = {c["effect"]: c for c in ef["candidates"] if c["round"] == 1 and "+" not in c["effect"]}
    assert set(first) == offered - {"delay"} and ef["skipped"] == ["delay"]
    for c in first.values():
        names = c["parameter"].split(", ")
        assert set(names) <= set(c["values"]) and all(np.isfinite(c["values"][n]) for n in names)
        assert set(c["held_out_gains"]) >= {"y", "i"}
    assert "amplifier_lag" not in first and ef["offered"]["amplifier_lag"].startswith("not for a voltage drive")
    # the report's table names them too
    text = (tmp_path / "report.md").read_text()
    assert all(f"| {n} |" in text for n in first)
