"""The mjsafe command line inside this Python process, with the filters and nominal
controllers your modules register (docs/python.md, "From the shell"):

    python -m mjsafe --load my_filters.py run scenario.toml --set 'filter={kind="margin_cbf"}'
    python -m mjsafe --load my_filters.py sweep --sweep my.sweep.toml
    python -m mjsafe --load my_filters.py falsify scenario.toml --range … --out logs/f
    python -m mjsafe --load my_filters.py scorecard --filter '{kind="margin_cbf"}' --out logs/s

Every subcommand and flag is the `mjsafe` binary's; `--load FILE.py` (or a module name) runs
the file first, so that its `mjsafe.register_filter`/`register_nominal` calls make the kinds
known, and may be given several times. `MJSAFE_LOAD` (paths separated by `:`) loads too.
Why an entry point of the package rather than an interpreter embedded in the binary: the user's
module runs in the Python (and the venv) it was written for, with its own packages (numpy,
cvxpy, torch), and the binary stays free of libpython.
"""

from __future__ import annotations

import importlib
import os
import runpy
import sys

from mjsafe import _core


def load(spec: str) -> None:
    """Runs a Python file (a path ending in .py) or imports a module by name."""
    if spec.endswith(".py") or os.sep in spec:
        if not os.path.isfile(spec):
            raise SystemExit(f"error: --load {spec}: no such file")
        runpy.run_path(spec, run_name="mjsafe_loaded")
    else:
        importlib.import_module(spec)


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    loads = [p for p in os.environ.get("MJSAFE_LOAD", "").split(":") if p]
    while args and args[0] in ("--load", "-l") or (args and args[0].startswith("--load=")):
        if args[0].startswith("--load="):
            loads.append(args.pop(0).split("=", 1)[1])
            continue
        if len(args) < 2:
            raise SystemExit("error: --load: expected a Python file or module name")
        args.pop(0)
        loads.append(args.pop(0))
    for spec in loads:
        load(spec)
    return _core.cli(["mjsafe", *args])


if __name__ == "__main__":
    sys.exit(main())
