"""The record format: good records load, bad ones fail naming file, line and column."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from maglev_cosim.records.record import RecordError, read_record, write_record

HEAD = "# ts: 0.001\n# controller: pid\n# kp: 2.0\n# ki: 2.97\n# kd: 0.01\n# u_min: 0.0\n# u_max: 1.0\n"


def good(k: int) -> str:
    """A plausible row: the ball moves a little around 3.2 mm."""
    return f"{k * 0.001:.4f},0.440000,0.439453,{0.392 + 0.01 * math.sin(k / 50):.6f}"


def make(tmp_path: Path, n: int = 2500, header: str = "t,w,u,y", meta: str = HEAD, row=good) -> Path:
    p = tmp_path / "rec.csv"
    p.write_text(meta + header + "\n" + "\n".join(row(k) for k in range(n)) + "\n")
    return p


def test_good_record_loads_with_metadata_and_any_column_order(tmp_path):
    p = make(tmp_path, header="y,extra,t,u,w", meta=HEAD + "# operator: jo\n",
             row=lambda k: f"{0.39209 + 1e-3 * (k % 2):.6f},abc,{k * 0.001:.4f},0.439453,0.440000")
    r = read_record(p)
    assert r.n == 2500 and r.ts == 0.001 and r.kp == 2.0 and r.ki == 2.97 and r.u_max == 1.0
    assert r.meta["operator"] == "jo"
    assert np.all(r.w == 0.44) and np.all(r.y[::2] == 0.39209) and r.warnings == [] and np.all(r.u == 0.439453)


def test_filter_and_anti_windup_metadata_reach_the_controller(tmp_path):
    from maglev_cosim.diagnosis.replay import record_controller

    t = np.arange(3000) * 1e-3
    w = 0.4 + 0.05 * (t > 1)
    p = write_record(tmp_path / "r.csv", t, w, w * 0.9, w * 1.01, ts=1e-3, kp=2.5, ki=3.0, kd=0.012,
                     u_min=0.0, u_max=1.0, tf=2e-3, anti_windup="clamping")
    pid = record_controller(read_record(p))
    assert (pid.kp, pid.tf, pid.anti_windup) == (2.5, 2e-3, "clamping")
    bad = p.read_text().replace("# anti_windup: clamping", "# anti_windup: sometimes")
    p.write_text(bad)
    with pytest.raises(RecordError) as ei:
        read_record(p)
    assert (ei.value.line, ei.value.column) == (9, 16) and "not one of none, conditional, clamping" in str(ei.value)


def test_round_trip_through_write_record(tmp_path):
    t = np.arange(3000) * 1e-3
    w = 0.4 + 0.05 * (t > 1)
    p = write_record(tmp_path / "r.csv", t, w, w * 0.9, w * 1.01, ts=1e-3, kp=2.0, ki=2.97, kd=0.01,
                     u_min=0.0, u_max=1.0, meta={"seed": "3"})
    r = read_record(p)
    assert np.allclose(r.w, w, atol=5e-7) and r.meta["seed"] == "3"


@pytest.mark.parametrize("case, line, column, words", [
    ("missing_column", 8, 1, "lacks column(s) y"),
    ("not_a_number", 9 + 5, 8, "'w': 'abc' is not a number"),
    ("nan", 9 + 7, 17, "not a finite number"),
    ("out_of_range", 9 + 3, 17, "outside the converter range"),
    ("not_increasing", 9 + 4, 1, "does not increase"),
    ("not_uniform", 9 + 4, 1, "not on the uniform grid"),
    ("ts_disagrees", 1, 7, "ts 0.002 disagrees"),
    ("too_short", 9 + 99, 1, "too short"),
    ("wrong_field_count", 9 + 2, 17, "3 fields"),
    ("too_many_fields", 9 + 6, 35, "5 fields"),
    ("duplicate_column", 8, 9, "'u' appears twice"),
    ("bom_then_bad_cell", 9 + 3, 8, "'w': 'x' is not a number"),
])
def test_bad_records_name_file_line_and_column(tmp_path, case, line, column, words):
    kw: dict = {}
    if case == "missing_column":
        kw = {"header": "t,w,u", "row": lambda k: f"{k * 0.001:.4f},0.44,0.43"}
    elif case == "not_a_number":
        kw = {"row": lambda k: good(k).replace("0.440000", "abc") if k == 5 else good(k)}
    elif case == "nan":
        kw = {"row": lambda k: good(k).replace("0.439453", "nan") if k == 7 else good(k)}
    elif case == "out_of_range":
        kw = {"row": lambda k: good(k).replace("0.439453", "1.500000") if k == 3 else good(k)}
    elif case == "not_increasing":
        kw = {"row": lambda k: good(2 if k == 4 else k)}
    elif case == "not_uniform":
        kw = {"row": lambda k: f"{k * 0.001 + (0.0004 if k == 4 else 0):.4f},0.44,0.43,{0.39 + 1e-3 * (k % 3)}"}
    elif case == "ts_disagrees":
        kw = {"meta": HEAD.replace("ts: 0.001", "ts: 0.002")}
    elif case == "too_short":
        kw = {"n": 100}
    elif case == "wrong_field_count":
        kw = {"row": lambda k: "0.0020,0.44,0.43" if k == 2 else good(k)}
    elif case == "too_many_fields":
        kw = {"row": lambda k: good(k) + ",7" if k == 6 else good(k)}
    elif case == "duplicate_column":
        kw = {"header": "t,w,u,y,u"}
    elif case == "bom_then_bad_cell":
        kw = {"meta": "\ufeff" + HEAD, "row": lambda k: good(k).replace("0.440000", "x") if k == 3 else good(k)}
    p = make(tmp_path, **kw)
    with pytest.raises(RecordError) as ei:
        read_record(p)
    e = ei.value
    assert (e.path, e.line, e.column) == (str(p), line, column), str(e)
    assert words in str(e) and str(e).startswith(f"{p}:{line}:{column}: ")


def test_missing_file_is_a_record_error(tmp_path):
    with pytest.raises(RecordError, match="file not found"):
        read_record(tmp_path / "nope.csv")


def test_bom_is_accepted(tmp_path):
    p = make(tmp_path)
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())
    assert read_record(p).n == 2500


def test_directory_is_one_clear_line(tmp_path):
    with pytest.raises(RecordError) as ei:
        read_record(tmp_path)
    assert str(ei.value) == f"{tmp_path}:0:0: is a directory, not a record file"


def test_unreadable_file_is_one_clear_line(tmp_path, monkeypatch):
    p = make(tmp_path)

    def refuse(self):   # chmod 000 does not stop root, so the operating system's refusal is simulated
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "read_bytes", refuse)
    with pytest.raises(RecordError) as ei:
        read_record(p)
    assert str(ei.value) == f"{p}:0:0: cannot be read: permission denied"


def test_undecodable_byte_names_its_line_and_character(tmp_path):
    p = make(tmp_path)
    lines = p.read_bytes().split(b"\n")
    lines[19] = "0.0100,0.44,0.4394,é".encode() + b"\xff"   # line 20: 'é' is one character, two bytes
    p.write_bytes(b"\n".join(lines))
    with pytest.raises(RecordError) as ei:
        read_record(p)
    assert (ei.value.line, ei.value.column) == (20, 21) and "byte 0xff is not UTF-8" in str(ei.value)


def test_bad_last_cell_of_a_long_record_is_located(tmp_path):
    n = 200_000
    p = make(tmp_path, n=n, row=lambda k: good(k) if k < n - 1 else good(k)[:-3] + "1e")
    with pytest.raises(RecordError) as ei:
        read_record(p)
    assert ei.value.line == 8 + n and "'y'" in str(ei.value)
    assert ei.value.column == len(good(n - 1).rsplit(",", 1)[0]) + 2


def plausibility_record(tmp_path: Path, y_of_k, u_of_k=lambda k: 0.44, w=0.44) -> Path:
    return make(tmp_path, n=3000, row=lambda k: f"{k * 0.001:.4f},{w},{u_of_k(k):.6f},{y_of_k(k):.6f}")


def wobble(k: int) -> float:
    return 0.44 + 0.01 * math.sin(k / 40)


@pytest.mark.parametrize("case, words", [
    ("constant", "y is constant at 0.44 MU"),
    ("y_pinned", "A/D limit of +-1 MU in 60.0 %"),
    ("u_pinned", "u sits at its limits (0 or 1 MU) in 60.0 %"),
    ("on_lower_stop", "rests on a stop in 100.0 %"),
])
def test_implausible_records_are_refused_at_the_signal_column(tmp_path, case, words):
    kw = {"constant": {"y_of_k": lambda k: 0.44},
          "y_pinned": {"y_of_k": lambda k: 1.0 if k >= 1200 else wobble(k)},
          "u_pinned": {"y_of_k": wobble, "u_of_k": lambda k: 1.0 if k % 5 < 3 else 0.5},
          "on_lower_stop": {"y_of_k": lambda k: 0.0025 + 1e-4 * (k % 2), "u_of_k": lambda k: 1.0 if k % 2 else 0.9},
          }[case]
    p = plausibility_record(tmp_path, **kw)
    with pytest.raises(RecordError) as ei:
        read_record(p)
    col = 5 if case == "u_pinned" else 7      # header "t,w,u,y"
    assert (ei.value.line, ei.value.column) == (8, col) and "implausible record" in str(ei.value), str(ei.value)
    assert words in str(ei.value)
    if case != "constant":   # below the refusal threshold, or asked to, it is read with a warning
        assert any(words.split(" in ")[0] in w for w in read_record(p, plausibility="warn").warnings)


def test_brief_troubles_are_warnings(tmp_path):
    p = plausibility_record(tmp_path, lambda k: 0.0025 if 1000 <= k < 1200 else wobble(k),
                            lambda k: 1.0 if 1000 <= k < 1400 else 0.44)
    r = read_record(p)
    assert len(r.warnings) == 2, r.warnings
    assert "rests on a stop in 6.7 %" in r.warnings[0] and "lower stop from t = 1.000 s for 0.200 s" in r.warnings[0]
    assert "u sits at its limits" in r.warnings[1] and "13.3 %" in r.warnings[1]
    assert read_record(plausibility_record(tmp_path, wobble)).warnings == []
