"""Refresh the results pages of docs/ from the newest outputs of the tools that measure them.

Each page (``docs/results/<name>.md``) has a hand-written head (what was measured, how to run it
again, what the figures mean) and a generated part between two markers, copied from the tool's
own output when that output exists on this machine:

- ``docs/results/bench.md`` <- ``bench/latest.md`` (``make bench``: its header names the date and
  the machine);
- ``docs/results/soak.md`` <- ``artifacts/soak/report.md`` (``make soak``);
- ``docs/results/fault-matrix.md`` <- ``artifacts/netlab/report.md`` (the network lab's rows:
  ``pytest tests/netlab`` records each row and kind, ``testkit/labrows.py`` renders the newest);
- ``docs/results/contact.md`` <- ``artifacts/contact/report.md`` (``python -m bench --only
  contact``: the family table, its header naming the date, the machine and the seed).

An output that is missing (``artifacts/`` is not committed) leaves the page's last generated part
as it is. Run by ``make docs``; ``--check`` exits 1 when a page is behind its output instead.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEGIN = "<!-- generated from {source} by scripts/docs_results.py (make docs): edit the source -->"
END = "<!-- end of the generated part -->"
PAGES = {
    "docs/results/bench.md": "bench/latest.md",
    "docs/results/soak.md": "artifacts/soak/report.md",
    "docs/results/fault-matrix.md": "artifacts/netlab/report.md",
    "docs/results/contact.md": "artifacts/contact/report.md",
}


def refreshed(page: str, source: str, root: Path = ROOT) -> str | None:
    """The page with its generated part replaced by ``source``'s text, or None without one."""
    output = root / source
    if not output.is_file():
        return None
    text = (root / page).read_text(encoding="utf-8")
    return replaced(page, text, source, output.read_text(encoding="utf-8"))


def replaced(page: str, text: str, source: str, body: str) -> str:
    """``text`` (of ``page``) with what lies between ``source``'s markers replaced by
    ``body``: the head and the tail, hand-written, are kept as they are."""
    begin = BEGIN.format(source=source)
    if begin not in text or END not in text.split(begin, 1)[1]:
        raise SystemExit(f"{page}: the markers of its generated part are missing ({begin})")
    head, rest = text.split(begin, 1)
    tail = rest.split(END, 1)[1]
    return f"{head}{begin}\n\n{body.strip()}\n\n{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    """Refresh every page whose output exists; with ``--check``, only say which are behind."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a page is behind")
    args = parser.parse_args(argv)
    behind = []
    for page, source in PAGES.items():
        new = refreshed(page, source, ROOT)
        if new is None:
            print(f"{page}: kept ({source} not here)")
            continue
        if new == (ROOT / page).read_text(encoding="utf-8"):
            print(f"{page}: up to date with {source}")
            continue
        behind.append(page)
        if not args.check:
            (ROOT / page).write_text(new, encoding="utf-8")
            print(f"{page}: refreshed from {source}")
    if args.check and behind:
        print(f"behind their outputs: {', '.join(behind)} (make docs)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
