"""``sara-app report SCENARIO``: the cell's evidence report as self-contained HTML (and PDF)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _report(args: argparse.Namespace) -> int:
    from sara_app.ops.audit import default_audit_path
    from sara_app.report.evidence import MODES, Settings, gather
    from sara_app.report.html import render
    from sara_app.report.pdf import print_pdf
    from sara_app.scenario import load_scenario

    sc = load_scenario(args.scenario)  # input errors before any output
    modes = [m.strip().lower() for m in args.modes.split(",") if m.strip()]
    bad = [m for m in modes if m not in MODES]
    if bad or not modes:
        print(f"error: --modes {args.modes!r}; valid choices: {', '.join(MODES)}", file=sys.stderr)
        return 2
    if args.episodes < 0:
        print(f"error: --episodes {args.episodes}; expected >= 0", file=sys.stderr)
        return 2
    audit = args.audit
    if audit is None and default_audit_path().exists():
        audit = default_audit_path()

    def progress(fraction: float, what: str) -> None:
        if not args.quiet:
            print(json.dumps({"progress": round(fraction, 3), "what": what}), file=sys.stderr,
                  flush=True)  # fmt: skip

    ev = gather(
        sc,
        Settings(args.recording, modes, args.duration, args.episodes, audit, args.cell),
        progress,
    )
    out = Path(args.out or f"{sc.name}-evidence.html")
    out.write_text(render(ev))
    if args.json:
        Path(args.json).write_text(json.dumps(ev.to_dict(), allow_nan=False))
    print(f"report: {out} (checksum {ev.checksum})")
    if args.pdf:
        print_pdf(out, Path(args.pdf))
        print(f"pdf: {args.pdf}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("report", help="evidence report of a cell (self-contained HTML, PDF)")
    r.add_argument("scenario", help="a name in scenarios/ or a scenario file path")
    r.add_argument("--out", default=None, help="HTML file (default: <scenario>-evidence.html)")
    r.add_argument("--pdf", default=None, help="also print it to this PDF (needs chromium)")
    r.add_argument("--json", default=None, help="also write the gathered evidence as JSON")
    r.add_argument("--recording", action="append", default=[],
                   help="a further recording to check containment on (repeatable)")  # fmt: skip
    r.add_argument("--modes", default="ssm,pfl,jssa", help="closed loops to run")
    r.add_argument("--duration", type=float, default=None,
                   help="seconds per closed loop (default: the scenario's)")  # fmt: skip
    r.add_argument("--episodes", type=int, default=5, help="adversarial episodes per mode")
    r.add_argument("--audit", type=Path, default=None,
                   help="audit database (default: the dashboard's, if it exists)")  # fmt: skip
    r.add_argument("--cell", default=None, help="the cell whose audit rows to include")
    r.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    r.set_defaults(run=_report)
