"""A sweep's run records, the sidecars under ``<out>/runs``: reading them (`load_runs`), writing them
atomically, and publishing and restoring them as one file (`save_records`, `restore_records`)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def _atomic_json(path: Path, data: Any) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def load_runs(out: str | Path, *, skipped: bool = False) -> list[dict[str, Any]]:
    """Every finished run's sidecar under ``out/runs`` (with ``skipped``, also the records of baselines
    that cannot act in their cell, which hold no test)."""
    runs = [json.loads(p.read_text()) for p in sorted((Path(out) / "runs").glob("*.json"))]
    return runs if skipped else [r for r in runs if not r.get("skipped")]


def save_records(out: str | Path, path: str | Path) -> int:
    """Write every finished run's sidecar of ``out`` into one gzipped JSON-lines file ``path``: the
    raw records a report is made from (every test episode's metrics, the learning curves, the
    settings), small enough to publish beside it.  Returns the number of records."""
    import gzip

    runs = load_runs(out, skipped=True)
    with gzip.open(path, "wt", encoding="utf-8") as fh:
        for r in runs:
            fh.write(json.dumps(r, sort_keys=True) + "\n")
    return len(runs)


def restore_records(path: str | Path, out: str | Path) -> int:
    """Write each record of a `save_records` file as a finished run's sidecar under ``out/runs``
    (unless that run is already there), so that a sweep over ``out`` skips those runs and its report
    includes them: how a published grid is continued, or its report remade, on another machine.
    The restored runs have no model files.  Returns the number of sidecars written."""
    import gzip

    runs = Path(out) / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    written = 0
    with gzip.open(path, "rt", encoding="utf-8") as fh:
        for line in fh:
            r = json.loads(line)
            dest = runs / f"{r['name']}.json"
            if not dest.exists():
                _atomic_json(dest, r)
                written += 1
    return written
