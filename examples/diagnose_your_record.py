"""Diagnose a closed-loop record: write one (here from the rig emulator), read it, diagnose it.
``load`` reads every format (a CE152 CSV; a real rig's record with ``rig=``); ``diagnose`` takes any."""
import sys
import tempfile
from pathlib import Path

from maglev_cosim.diagnosis import diagnose
from maglev_cosim.records.load import load
from maglev_cosim.records.synth import synth_record

folder = Path(tempfile.mkdtemp())
path = Path(sys.argv[1]) if len(sys.argv) > 1 else synth_record(folder / "rec.csv", duration=6.0, seed=4,
                                                                    effects={"delay": {"T_d": 0.003}})
rec = load(path)                                         # your own record: docs/record-format.md
d = diagnose(rec, effects=["delay", "amplifier_lag"], workers=1)     # out=FOLDER: the report and FMU too
print(f"{path.name}: verdict {d.verdict}; selected {d.selected or 'none'}; rms_y before {d.before.rms_y:.2e} MU, "
      f"after {d.after.rms_y:.2e} MU")
for p in d.parameters.values():
    if p.sigma is not None and p.name in ("T_d", "T_a"):
        print(f"  {p}")
