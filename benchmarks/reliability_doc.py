"""Each reliability harness rewrites its own section of ``docs/reliability.md``.

A section lies between ``<!-- BEGIN name -->`` and ``<!-- END name -->``; the rest of the page
(its introduction, the other harnesses' sections) is left as it is, so the harnesses can be run
one at a time and the page always shows the figures of each one's last run.
"""

from __future__ import annotations

import os
import platform
import re
import time
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "reliability.md"


def provenance(command: str) -> str:
    """One line saying when, where and how a section's figures were measured."""
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return (f"*Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} on {platform.machine()} "
            f"({os.cpu_count()} cores, load {load}) by `{command}`.*")


def write_section(name: str, markdown: str, doc: Path = DOC, title: str = "# Reliability") -> None:
    """Replace section ``name`` of the page ``doc`` with ``markdown`` (appended when the page lacks
    it; a missing page starts with ``title``)."""
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    block = f"{begin}\n{markdown.strip()}\n{end}"
    text = doc.read_text(encoding="utf-8") if doc.exists() else f"{title}\n"
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.DOTALL)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else text.rstrip() + "\n\n" + block + "\n"
    tmp = doc.with_suffix(".md.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(doc)
