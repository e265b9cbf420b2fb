"""The ``sara-app`` command line."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from sara_app import commands
from sara_app.errors import SaraError


def build_parser() -> argparse.ArgumentParser:
    """One sub-command group per module of :mod:`sara_app.commands` (sorted by module name; a
    module whose name starts with ``_`` serves the others)."""
    ap = argparse.ArgumentParser(prog="sara-app", description=__doc__)
    sub = ap.add_subparsers(dest="command", required=True)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        rc = args.run(args)
    except SaraError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
