"""An effect is declared once, in the C variable table's ``effect`` column (docs/adding-an-effect.md):
the catalogue, synth, both emulators, PlantParams and the model descriptions take their lists from it."""

from __future__ import annotations

from dataclasses import fields

from fmpy import read_model_description

from maglev_cosim.diagnosis.effects import CATALOGUE, DEFAULT_EFFECTS
from maglev_cosim.plant.fast import effect_params, param_effects, param_table
from maglev_cosim.plant.params import EFFECT_PARAMS, SOURCES, PlantParams
from maglev_cosim.records import emulator, emulator_ivp, synth


def test_every_parameter_has_an_effect_column_and_effects_group_parameters():
    effects = param_effects()
    assert list(effects) == list(param_table())
    assert effects["T_d"] == "delay" and effects["k_c"] == "" and effects["solver_step"] == ""
    assert EFFECT_PARAMS == effect_params()
    assert EFFECT_PARAMS["periodic_disturbance"] == ("A_d", "f_d", "phi_d")
    assert all(SOURCES[p].startswith("effect") or SOURCES[p] for p in effects)


def test_the_catalogue_is_the_table_s_effects():
    """One entry per effect of the table, each with the table's parameters, an example magnitude
    within the table's ranges and the search bounds inside them."""
    table = param_table()
    assert set(CATALOGUE) == set(EFFECT_PARAMS)
    assert set(DEFAULT_EFFECTS) <= set(CATALOGUE)
    for name, eff in CATALOGUE.items():
        assert eff.params == EFFECT_PARAMS[name]
        assert eff.example and set(eff.example) <= set(eff.params), name
        for p, v in eff.example.items():
            assert table[p][1] <= v <= table[p][2], (name, p)
        PlantParams().replace(**eff.example).validate()
        for c in eff.coords:
            if c.name in table:
                assert table[c.name][1] <= c.lo < c.hi <= table[c.name][2], (name, c)


def test_the_emulators_know_the_table_s_effects_by_their_fields():
    """The rig emulator writes every effect of the catalogue (synth takes each by the table's
    names); the independent one those it has fields for; both with the table's parameter names."""
    rig_fields = {f.name for f in fields(emulator.RigConfig)}
    assert synth.EFFECTS is emulator.EFFECTS
    for name, params in EFFECT_PARAMS.items():
        assert name in synth.EFFECTS, name
        assert synth.EFFECTS[name] == tuple(p for p in params if p in rig_fields)
    assert set(synth.EFFECTS) - set(EFFECT_PARAMS) == set(emulator.OUTSIDE_CATALOGUE)
    for name, params in emulator_ivp.EFFECTS.items():
        assert set(params) <= set(EFFECT_PARAMS[name])
    assert {"delay", "force_lag", "coulomb_friction"} <= set(emulator_ivp.EFFECTS)


def test_synth_accepts_every_catalogue_effect_at_its_example():
    for name, eff in CATALOGUE.items():
        spec = f"{name}:" + ",".join(f"{k}={v!r}" for k, v in eff.example.items() if k in synth.EFFECTS[name])
        assert synth.parse_effect_spec(spec)[0] == name


def test_model_descriptions_name_each_parameter_s_effect(repo):
    """Each effect parameter's description in the committed model descriptions says its effect."""
    for xml in ("modelDescription.xml", "modelDescription3.xml"):
        md = read_model_description(str(repo / xml))
        desc = {v.name: v.description for v in md.modelVariables}
        for name, effect in param_effects().items():
            assert (f"effect {effect}" in desc[name]) == bool(effect), (xml, name, desc[name])
