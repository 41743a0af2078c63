"""The one loader (maglev_cosim.records.load): every format into one type, ``Recording``; a record
that does not fit its rig refused in one line saying what it is; bad data still refused at its file,
line and column."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io

from maglev_cosim.records.load import Recording, WrongRig, load, load_all
from maglev_cosim.records.record import RecordError
from maglev_cosim.records.synth import synth_record
from maglev_cosim.rigs import load_rig


def _ce152(path):
    return synth_record(path, duration=2.0, seed=1)


def _inteco(path, n: int = 2000):
    """A MATLAB level-5 file with the Inteco results' ``logouts`` rows (time, reference, gap, ...)."""
    t = np.arange(n) * 1e-3
    rows = np.zeros((14, n))
    rows[0], rows[1], rows[2] = t, 0.012, 0.012 + 1e-4 * np.sin(5 * t)
    rows[4], rows[6], rows[12] = 1.0, 0.3, 0.3
    scipy.io.savemat(path, {"logouts": rows})
    return path


def _levitador(path, n: int = 400):
    path.write_text("".join(f"{k * 0.01:.2f} 0.005 {0.005 + 1e-5 * (k % 4):.6f} 0.8 0.8 9.8\n" for k in range(n)))
    return path


def _session(path, n: int = 400, columns: str = "t y i u yd"):
    sig = {"t": lambda k: f"{k * 0.01:.4f}", "y": lambda k: f"{0.005 + 4.888e-5 * (k % 5):.6f}",
           "i": lambda k: "0.4000", "u": lambda k: f"{6 + 0.1 * (k % 7):.4f}", "yd": lambda k: "0.005000"}
    head = f"# Dataset Levitador Magnético\n# Ts: 0.01s\n# Columnas: {columns}\n#\n"
    path.write_bytes((head + "".join("\t".join(sig[c](k) for c in columns.split()) + "\n"
                                     for k in range(n))).encode("latin-1"))
    return path


def test_a_ce152_record_loads_as_a_recording(tmp_path):
    r = load(_ce152(tmp_path / "rec.csv"))
    assert isinstance(r, Recording) and r.kind == "ce152" and r.format == "ce152" and r.rig is None
    assert r.ce152 is not None and r.measured is None and r.ts == pytest.approx(1e-3) and r.n == r.ce152.n
    assert load(tmp_path / "rec.csv", "ce152").kind == "ce152"


def test_an_inteco_mat_loads_with_its_rig(tmp_path):
    r = load(_inteco(tmp_path / "MPC - KF.mat"), "inteco-mls2em")
    assert r.kind == "rig" and r.format == "inteco-mat" and r.rig.name == "inteco-mls2em"
    assert r.measured.drive is not None and r.ts == pytest.approx(1e-3) and r.n == 2000


def test_the_levitador_formats_load_with_their_rig(tmp_path):
    rig = load_rig("levitador")
    old = load(_levitador(tmp_path / "datos.txt"), rig)
    new = load(_session(tmp_path / "sesion.txt"), rig)
    assert (old.format, new.format) == ("levitador", "columns") and old.rig is rig and new.rig is rig
    assert old.measured.current is not None and new.measured.drive is not None
    assert any("Latin-1" in w for w in new.warnings)
    # several records, one rig
    both = load_all([tmp_path / "datos.txt", tmp_path / "sesion.txt"], "levitador")
    assert [r.format for r in both] == ["levitador", "columns"] and both[0].rig is both[1].rig


def test_a_ce152_record_given_a_real_rig_says_what_it_is(tmp_path):
    f = _ce152(tmp_path / "rec.csv")
    with pytest.raises(WrongRig, match="is a CE152-format record .* --rig inteco-mls2em does not fit it"):
        load(f, "inteco-mls2em")


def test_a_real_record_without_its_rig_says_which_it_likely_needs(tmp_path):
    f = _session(tmp_path / "sesion.txt")
    with pytest.raises(WrongRig, match="a real rig's record: name its rig with --rig .*likely --rig levitador"):
        load(f)
    with pytest.raises(WrongRig, match="not a CE152-format record: --rig ce152 does not fit it"):
        load(f, "ce152")


def test_bad_data_is_still_refused_at_file_line_and_column(tmp_path):
    f = _ce152(tmp_path / "rec.csv")
    lines = f.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln and ln[0].isdigit()) + 3
    cells = lines[k].split(",")
    cells[2] = "x"
    lines[k] = ",".join(cells)
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordError) as e:
        load(f)
    assert e.value.line == k + 1 and e.value.column > 1 and str(e.value).startswith(f"{f}:{k + 1}:")
    g = _session(tmp_path / "no_drive.txt", columns="t y i yd")
    with pytest.raises(RecordError, match="no column for the actuator signal"):
        load(g, "levitador")
    assert load(g, "levitador", require=()).measured.drive is None
