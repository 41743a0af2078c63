"""The record format: good records load, bad ones fail naming file, line and column."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from maglev_cosim.record import RecordError, read_record, write_record

HEAD = "# ts: 0.001\n# controller: pid\n# kp: 2.0\n# ki: 2.97\n# kd: 0.01\n# u_min: 0.0\n# u_max: 1.0\n"


def make(tmp_path: Path, n: int = 2500, header: str = "t,w,u,y", meta: str = HEAD,
         row=lambda k: f"{k * 0.001:.4f},0.440000,0.439453,0.392090") -> Path:
    p = tmp_path / "rec.csv"
    p.write_text(meta + header + "\n" + "\n".join(row(k) for k in range(n)) + "\n")
    return p


def test_good_record_loads_with_metadata_and_any_column_order(tmp_path):
    p = make(tmp_path, header="y,extra,t,u,w", meta=HEAD + "# operator: jo\n",
             row=lambda k: f"0.392090,abc,{k * 0.001:.4f},0.439453,0.440000")
    r = read_record(p)
    assert r.n == 2500 and r.ts == 0.001 and r.kp == 2.0 and r.ki == 2.97 and r.u_max == 1.0
    assert r.meta["operator"] == "jo"
    assert np.all(r.w == 0.44) and np.all(r.y == 0.39209) and np.all(r.u == 0.439453)


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
    ("wrong_field_count", 9 + 2, 4, "3 fields"),
])
def test_bad_records_name_file_line_and_column(tmp_path, case, line, column, words):
    good = lambda k: f"{k * 0.001:.4f},0.440000,0.439453,0.392090"  # noqa: E731
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
        kw = {"row": lambda k: f"{k * 0.001 + (0.0004 if k == 4 else 0):.4f},0.44,0.43,0.39"}
    elif case == "ts_disagrees":
        kw = {"meta": HEAD.replace("ts: 0.001", "ts: 0.002")}
    elif case == "too_short":
        kw = {"n": 100}
    elif case == "wrong_field_count":
        kw = {"row": lambda k: "0.0020,0.44,0.43" if k == 2 else good(k)}
    p = make(tmp_path, **kw)
    with pytest.raises(RecordError) as ei:
        read_record(p)
    e = ei.value
    assert (e.path, e.line, e.column) == (str(p), line, column), str(e)
    assert words in str(e) and str(e).startswith(f"{p}:{line}:{column}: ")


def test_missing_file_is_a_record_error(tmp_path):
    with pytest.raises(RecordError, match="file not found"):
        read_record(tmp_path / "nope.csv")
