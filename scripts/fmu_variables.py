"""Markdown tables of the FMU's variables, read from modelDescription.xml (not written by hand).

    python scripts/fmu_variables.py [--key] [--out FILE] [modelDescription.xml]

prints (or writes into FILE) one table row per variable: name, causality, unit, start, range (min to
max) and the description. ``--key`` keeps the variables the README lists (the input, the outputs and
the parameters a newcomer sets first), without the range. README.md carries the ``--key`` table
verbatim (tests/test_readme.py checks it); the whole table is not committed: the build writes it to
``build/fmu_variables.md`` (CMakeLists.txt), and docs/fmu.md points there
(tests/test_model_description.py checks it against the C table).
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: The README's rows: the input, the outputs, the start state, the parameters of Eq. 1/2/8/13 a
#: user changes first, the stops and the current limit, and one effect (the delay).
KEY = ("u", "y", "x", "v", "i", "F", "x_start", "v_start", "i_start", "k_DA", "k_AD", "T_a", "k_c", "x_0",
       "k_FV", "i_max", "T_d")


def _cell(text: str | None) -> str:
    return "" if text is None else text.replace("|", "\\|")


def rows(xml_path: str | Path, names: tuple[str, ...] | None = None, *, with_range: bool = True) -> list[str]:
    root = ET.parse(xml_path).getroot()
    found = {}
    for sv in root.iter("ScalarVariable"):
        real = sv.find("Real")
        a = real.attrib if real is not None else {}
        lo, hi = a.get("min"), a.get("max")
        rng = f" {lo} to {hi} |" if lo is not None and hi is not None else " |"
        found[sv.get("name")] = (f"| `{sv.get('name')}` | {sv.get('causality')} | {_cell(a.get('unit'))} | "
                                 f"{_cell(a.get('start'))} |{rng if with_range else ''} {_cell(sv.get('description'))} |")
    order = names if names is not None else tuple(found)
    missing = [n for n in order if n not in found]
    if missing:
        raise SystemExit(f"{xml_path}: no variable {', '.join(missing)}")
    return [found[n] for n in order]


def table(xml_path: str | Path = REPO / "modelDescription.xml", *, key: bool = False) -> str:
    if key:
        head = ["| name | causality | unit | start | description |", "|---|---|---|---|---|"]
        return "\n".join(head + rows(xml_path, KEY, with_range=False)) + "\n"
    head = ["| name | causality | unit | start | range | description |", "|---|---|---|---|---|---|"]
    return "\n".join(head + rows(xml_path)) + "\n"


def main(argv: list[str]) -> int:
    key = "--key" in argv
    args = [a for a in argv if a != "--key"]
    out = None
    if "--out" in args:
        k = args.index("--out")
        out = Path(args[k + 1]) if k + 1 < len(args) else None
        args = args[:k] + args[k + 2:] if out else ["-"]
    if len(args) > 1 or any(a.startswith("-") for a in args):
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    text = table(args[0] if args else REPO / "modelDescription.xml", key=key)
    if out is None:
        sys.stdout.write(text)
    else:
        out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
