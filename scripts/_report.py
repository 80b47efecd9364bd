"""The common ending of the scripts' main(): OUT/results.json written atomically, then JSON or a table on stdout."""
from __future__ import annotations

import json
from pathlib import Path

from planner.result import write_atomically


def report(out: Path, results, table: str, as_json: bool, printed=None) -> int:
    """Write `results` to out/results.json (atomically; out created), print `printed` (default: results) as JSON
    when as_json, else `table`; return 0, main()'s exit code."""
    out.mkdir(parents=True, exist_ok=True)
    write_atomically(out / "results.json", json.dumps(results, indent=1, default=str) + "\n")
    print(json.dumps(results if printed is None else printed, indent=1, default=str) if as_json else table)
    return 0
