"""Records that do not start settled (maglev_cosim/records/settled.py): a record cut from a running
loop is read from where its loop is first as quiet as in its own settled stretches, and its replays
start where it began, the error standing."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from maglev_cosim.diagnosis import pipeline
from maglev_cosim.diagnosis.controller_form import identified
from maglev_cosim.diagnosis.engine import diagnose
from maglev_cosim.diagnosis.replay import baseline_params, replay
from maglev_cosim.diagnosis.residual import check_controller
from maglev_cosim.records import settled
from maglev_cosim.records.record import read_record
from maglev_cosim.records.synth import draw_disturbance, synth_record


def _cut(rec, after_step: int = 2, t_min: float = 1.0):
    """``rec`` from ``after_step`` samples after its first reference step at or after ``t_min`` [s],
    re-timed to start at 0: a logger started while the ball flies."""
    steps = np.nonzero(np.abs(np.diff(rec.w)) > 1e-12)[0] + 1
    k = int(steps[rec.t[steps] >= t_min][0]) + after_step
    return replace(rec, t=rec.t[k:] - rec.t[k], w=rec.w[k:], u=rec.u[k:], y=rec.y[k:])


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    seed = 7701
    path = synth_record(tmp_path_factory.mktemp("settled") / "r.csv", seed=seed, disturbance=draw_disturbance(seed))
    return read_record(path, plausibility="warn")


def test_a_record_that_starts_settled_is_read_whole(record):
    assert settled.settled_from(record) == (0, None)
    same, text = settled.from_settled(record)
    assert same is record and text is None


def test_a_record_cut_while_the_ball_flies_is_read_from_where_its_loop_is_quiet(record):
    cut = _cut(record)
    k, text = settled.settled_from(cut)
    assert 0 < k <= int(0.5 / cut.ts) and "does not start settled" in text and f"sample {k}" in text
    n = int(round(settled.WINDOW_S / cut.ts))
    # the first window moves several times more than the window it is read from
    assert np.std(cut.y[:n]) > 4 * np.std(cut.y[k:k + n])
    trimmed, warning = settled.from_settled(cut)
    assert trimmed.n == cut.n - k and trimmed.t[0] == cut.t[k] and warning in trimmed.warnings
    assert settled.settled_from(trimmed) == (0, None)          # read once, it starts settled


@pytest.mark.parametrize("before_step", [5, 50, 120])
def test_a_record_at_rest_that_steps_soon_after_it_begins_is_read_whole(record, before_step):
    """Cut while at rest, 5 to 120 ms before a reference step: the step's response is no motion of
    the start, which is read as settled."""
    assert settled.settled_from(_cut(record, after_step=-before_step)) == (0, None)


def test_the_cut_record_passes_the_controller_check_once_read_from_its_settled_start(record):
    """Started settled at zero error, the declared PID ran on the cut record misses its u by far
    (the check refused it as another controller's); read from where it settles, it fits."""
    cut = _cut(record)
    rec, _ = identified(cut)
    assert check_controller(rec) > 0.0


def test_a_reference_that_never_rests_cannot_tell_and_the_record_is_read_whole(tmp_path):
    rec = read_record(synth_record(tmp_path / "s.csv", reference="sine", duration=6.0, seed=3), plausibility="warn")
    assert settled.settled_from(rec) == (0, None)
    assert settled.settled_from(_cut(rec, t_min=1.3)) == (0, None)     # cut anywhere: it cannot tell


def test_the_replay_starts_where_the_record_began_at_rest(record):
    """Read from where it settles after the cut, the loop still creeps towards its reference (its integrator winds):
    the replay's ball rests where the record began, its output holding it, rather than jumping
    towards the reference at once (kp times the standing error, and a derivative kick)."""
    cut, _ = settled.from_settled(_cut(record))
    y_b = cut.y_before
    assert y_b == settled.standing_reading(cut.y, cut.ts) and abs(cut.w[0] - y_b) > 0.003     # an error stands
    r = replay(cut, baseline_params())
    assert abs(r["y"][20] - y_b) < 0.2 * abs(cut.w[0] - y_b)
    # a record read from its first sample starts at zero error, as before
    assert settled.from_settled(record)[0].y_before is None


@pytest.mark.slow
@pytest.mark.parametrize("effects, expected", [({}, []), ({"amplifier_lag": {"T_a": 3e-3}}, ["amplifier_lag"])])
def test_a_record_cut_from_a_running_loop_is_diagnosed_as_the_whole_one(tmp_path, effects, expected):
    """Project emulator, seed 7701, without effects (before, the check refused the cut record, and
    with the check skipped the start's transient made a 0.08 ms amplifier lag) and with a 3 ms
    amplifier lag (found at 3.04 ms whole, 2.84 ms cut), each cut 2 ms after its first step after 1 s."""
    seed = 7701
    rec = read_record(synth_record(tmp_path / "r.csv", seed=seed, disturbance=draw_disturbance(seed), effects=effects),
                      plausibility="warn")
    cut = _cut(rec)
    if effects:
        # the whole path a user takes: the report, the comparison with the black box (fitted on the
        # record as the diagnosis reads it) and the calibrated FMU
        res = diagnose(cut, out=tmp_path / "out")
        assert res.selected == expected and (tmp_path / "out" / "report.html").exists()
        assert any("does not start settled" in w for w in res.warnings)
        return
    d = pipeline.run(cut)
    assert d.selected == expected
    assert any("does not start settled" in w for w in d.record_warnings)
