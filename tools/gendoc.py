"""The command line the doc generators share (tools/gen_*.py): write the document, or with
--check compare it with what is committed (exit 1 when stale)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def generator_main(render: Callable[[], str], out: Path, script: str, source: str, doc: str, argv=None) -> int:
    """``render()`` written to ``out``, or checked against it (``source``: what it is made from)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare instead of writing")
    args = ap.parse_args(argv)
    text = render()
    name = out.relative_to(ROOT)
    if args.check:
        if not out.is_file() or out.read_text(encoding="utf-8") != text:
            print(f"{name} is stale: run `python tools/{script}`", file=sys.stderr)
            return 1
        print(f"{name} matches {source}")
        return 0
    out.write_text(text, encoding="utf-8")
    print(f"wrote {name}")
    return 0
