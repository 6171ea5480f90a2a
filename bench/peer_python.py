"""What the benchmark drivers share: the peers' interpreter, and reading a child's JSON figures.

`make bench` passes `--python bench-out/torch-venv/bin/python`, a path relative to the repo; the
drivers run some children in other folders (cwd="/" or a work folder), so the path is made
absolute here once instead of failing with "No such file" in whichever child runs first. (Made
absolute, not resolved: resolving a venv's python symlink would run the base interpreter, without
the venv's packages.)
"""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DEFAULT = REPO / "bench-out" / "torch-venv" / "bin" / "python"


def resolve(arg: str | None, packages: str) -> str:
    """`arg` (a path, or a command name on PATH) as an absolute path, else the default venv's
    interpreter; exits with how to create it when there is none. `packages`: what the peer needs."""
    hint = f"python3 -m venv bench-out/torch-venv && bench-out/torch-venv/bin/pip install {packages}"
    if arg:
        found = Path(arg).absolute() if "/" in arg else shutil.which(arg)
        if found is None or not Path(found).exists():
            sys.exit(f"--python {arg}: no such interpreter")
        return str(found)
    if DEFAULT.exists():
        return str(DEFAULT)
    sys.exit(f"no interpreter for the peer: {DEFAULT} does not exist.\n"
             f"Create it (from the repo root) with:\n    {hint}\nor pass --python PATH.")


def last_json(text: str, key: str = "updates_per_sec") -> dict | None:
    """A child's figures: the last line of its output that is a JSON object holding `key`
    (anything it logs before that is ignored)."""
    for line in reversed(text.splitlines()):
        line = line.strip()
        if line.startswith("{"):
            try:
                doc = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(doc, dict) and key in doc:
                return doc
    return None


def tail(path: Path, n: int = 30) -> str:
    """The last `n` lines of a log, for a failure's message ("" when it cannot be read)."""
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""
