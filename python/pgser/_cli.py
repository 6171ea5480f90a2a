"""The wheel's `pgser-etl` and `pgser-train` commands (console scripts of the wheel that
`make wheel` builds): each runs the bundled binary `pgser/bin/pgser` under its own name, which
makes it pgser-etl or pgser-train. The process is replaced, so signals, exit codes and the
terminal go to the binary as if it had been started directly."""

import os
import sys
from pathlib import Path


def _run(name):
    exe = Path(__file__).parent / "bin" / "pgser"
    if not exe.is_file():
        sys.exit(
            f"{name}: this pgser has no bundled commands (a developer build from `make python` or "
            f"`pip install ./python`): run the clone's target/release/{name}, or install the wheel of `make wheel`"
        )
    os.execv(exe, [name, *sys.argv[1:]])


def etl():
    _run("pgser-etl")


def train():
    _run("pgser-train")
