"""Where the tests find the shared real records (public, MIT; ../shared/data/real/README.md):
$MAGLEV_REAL_DATA, else ../shared/data/real beside the clone, else the development machine's
/work/shared/data/real. Tests needing them skip where none is found."""

from __future__ import annotations

import os
from pathlib import Path


def _real_data() -> Path:
    if "MAGLEV_REAL_DATA" in os.environ:
        return Path(os.environ["MAGLEV_REAL_DATA"])
    for p in (Path(__file__).resolve().parents[2] / "shared" / "data" / "real", Path("/work/shared/data/real")):
        if p.is_dir():
            return p
    return Path("/nonexistent")


REAL = _real_data()
