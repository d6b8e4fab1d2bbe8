"""Write ``src/vispeech/phonetics/data/panphon.tsv`` from the installed ``panphon`` package.

Run from the repository root after upgrading panphon (the ``test`` extra installs it)::

    python tests/panphon_table.py

vispeech reads PanPhon's feature rows from that file, so that the core install needs neither
panphon nor the pandas it pulls. The rows are those of PanPhon's ``ipa_all.csv`` for the base
segments of its ``ipa_bases.csv`` (tone letters left out), NFD-normalised, in the bases'
order, their values as PanPhon writes them (``+``, ``-``, ``0``); the header carries PanPhon's
credit and MIT licence. tests/test_ipa.py checks that the file is what this script writes.
"""

from __future__ import annotations

import csv
import unicodedata
from importlib.metadata import distribution, version
from importlib.util import find_spec
from pathlib import Path

TABLE = Path(__file__).resolve().parents[1] / "src" / "vispeech" / "phonetics" / "data" / "panphon.tsv"
TONE_LETTERS = "˥˦˧˨˩꜈꜉꜊꜋꜌"


def _notice() -> list[str]:
    """PanPhon's provenance, credit and licence (its distribution's LICENSE file), as comment lines."""
    files = distribution("panphon").files or ()
    licence = next(Path(str(f.locate())).read_text(encoding="utf-8") for f in files if f.name.startswith("LICENSE"))
    lines = [
        f"PanPhon {version('panphon')} (David R. Mortensen et al., https://github.com/dmort27/panphon):",
        "the rows of data/ipa_all.csv for the base segments of data/ipa_bases.csv, tone letters left out,",
        "NFD-normalised; written by tests/panphon_table.py. PanPhon's licence:",
        "",
        *"\n\n".join(part.strip() for part in licence.split("\n\n") if part.strip()).splitlines(),
    ]
    return [f"# {line}".rstrip() for line in lines]


def table_text() -> str:
    """The table as this script writes it, from the installed panphon."""
    spec = find_spec("panphon")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("panphon is not installed (pip install panphon)")
    data = Path(list(spec.submodule_search_locations)[0]) / "data"
    with open(data / "ipa_bases.csv", encoding="utf-8", newline="") as f:
        bases = [unicodedata.normalize("NFD", row["ipa"]) for row in csv.DictReader(f)]
    wanted = {b for b in bases if not set(b) <= set(TONE_LETTERS)}
    rows: dict[str, list[str]] = {}
    with open(data / "ipa_all.csv", encoding="utf-8", newline="") as f:
        names = next(csv.reader(f))[1:]
        for line in f:
            fields = line.rstrip("\r\n").split(",")
            segment = unicodedata.normalize("NFD", fields[0])
            if segment in wanted:
                rows[segment] = fields[1:]
    lines = [*_notice(), "\t".join(["ipa", *names])]
    lines += ["\t".join([base, *rows[base]]) for base in dict.fromkeys(bases) if base in rows]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    TABLE.write_text(table_text(), encoding="utf-8")
    print(f"wrote {TABLE}")
