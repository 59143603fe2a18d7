"""The harness's constants and the small helpers its parts share."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path


ROOT = Path(__file__).resolve().parents[2]  # the checkout (this is tools/fuzzlib/common.py)
GiB = 1 << 30
MEM_BOUND = 2 * GiB  # peak RSS above the worker's warm baseline
CASE_TIMEOUT = 20.0  # s per command
READ_ONLY = {"list", "verify", "inspect", "hash", "export"}
BASES = ("h5", "zarr")
SAFE_DIRS = ("run", "run2", "out", "runs", "cache")  # under R/w: where commands may write
SIZE_BOUND = 300 << 20  # peak RSS above the RSS at the call of a refusal of a hostile declared size
# a run from a prepared bed or from the bed cache (the bed cases; tiny, with a commit and frames)
BED_RUN = [
    "run",
    "quick",
    "--steps",
    "4",
    "--checkpoint-every",
    "2",
    "--no-progress",
    "--no-figures",
    "--set",
    "output.series_interval=0.00002",
    "--set",
    "output.snapshot_interval=0.00002",
]


def _dumps(obj) -> str:
    """json.dumps, with the deep markers written as raw text (json.dumps would recurse too deep)."""
    raws = []

    def swap(v):
        if isinstance(v, dict) and len(v) == 1 and next(iter(v)) in ("$deep_list", "$deep_dict"):
            ((k, n),) = v.items()
            raws.append("[" * n + "]" * n if k == "$deep_list" else '{"a": ' * n + "{}" + "}" * n)
            return f"__RAW{len(raws) - 1}__"
        if isinstance(v, dict):
            return {k: swap(x) for k, x in v.items()}
        if isinstance(v, list):
            return [swap(x) for x in v]
        return v

    text = json.dumps(swap(obj), indent=1)
    for i, r in enumerate(raws):
        text = text.replace(f'"__RAW{i}__"', r, 1)
    return text


def _sha(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _opt(argv, name):
    for i, a in enumerate(argv):
        if a == name and i + 1 < len(argv):
            return argv[i + 1]
        if a.startswith(name + "="):
            return a.split("=", 1)[1]
    return None
