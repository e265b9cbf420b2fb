"""``sara-app report SCENARIO``: the cell's evidence report as self-contained HTML (and PDF)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from sara_app.options import SECONDS, whole
from sara_app.processes.defaults import API_PORT


def _report(args: argparse.Namespace) -> int:
    if args.scenario is None:
        if args.cell is None:
            print("error: give a scenario (name or file) or --cell CELL (a running cell)",
                  file=sys.stderr)  # fmt: skip
            return 2
        return _running_cell_report(args)
    return _file_report(args)


def _file_report(args: argparse.Namespace) -> int:
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
    audit = args.audit
    if audit is None and default_audit_path().exists():
        audit = default_audit_path()
    source = (f"the scenario {args.scenario!r} as its file says, NOT a running cell (a running "
              "cell's report: sara-app report --cell CELL)")  # fmt: skip
    print(f"this report describes {source}")

    def progress(fraction: float, what: str) -> None:
        if not args.quiet:
            print(json.dumps({"progress": round(fraction, 3), "what": what}), file=sys.stderr,
                  flush=True)  # fmt: skip

    settings = Settings(args.recording, modes, args.duration, args.episodes, audit, args.cell,
                        source)  # fmt: skip
    ev = gather(sc, settings, progress)
    out = Path(args.out or f"{sc.name}-evidence.html")
    out.write_text(render(ev))
    if args.json:
        Path(args.json).write_text(json.dumps(ev.to_dict(), allow_nan=False))
    print(f"report: {out} (checksum {ev.checksum})")
    if args.cell is not None:
        _compare_with_running(args, ev.checksum)
    if args.pdf:
        print_pdf(out, Path(args.pdf))
        print(f"pdf: {args.pdf}")
    return 0


def _compare_with_running(args: argparse.Namespace, checksum: str) -> None:
    """Say whether the running cell ``args.cell`` (if its API answers) runs what the file says."""
    from sara_app.errors import SaraError

    try:
        running = _api(args, "GET", f"/api/cells/{args.cell}").get("config_sha256")
    except SaraError as e:
        print(f"the running cell {args.cell!r} could not be asked ({e}): checksums not compared")
        return
    same = "the same configuration" if running == checksum else "a DIFFERENT configuration"
    print(f"the running cell {args.cell!r} runs checksum {running}: {same} as this file")


def _running_cell_report(args: argparse.Namespace) -> int:
    """The evidence report of the cell as it runs, made by the API (a background job on the
    scenario the cell reports, live edits included), saved beside its checksum."""
    import time

    params = {"episodes": args.episodes} | ({} if args.duration is None else
                                            {"duration_s": args.duration})  # fmt: skip
    job = _api(args, "POST", f"/api/cells/{args.cell}/report", params)
    print(f"this report describes the running cell {args.cell!r} (job {job['id']})")
    while (st := _api(args, "GET", f"/api/jobs/{job['id']}"))["state"] == "running":
        if not args.quiet:
            print(json.dumps({"progress": st.get("progress"), "what": st.get("what")}),
                  file=sys.stderr, flush=True)  # fmt: skip
        time.sleep(1.0)
    if st["state"] != "done":
        print(f"error: the report job {st['state']}: {st.get('error', '')}", file=sys.stderr)
        return 1
    out = Path(args.out or f"{args.cell}-evidence.html")
    out.write_text(_api(args, "GET", st["report_url"], text=True))
    running = _api(args, "GET", f"/api/cells/{args.cell}").get("config_sha256")
    same = (
        "equal"
        if running == st["checksum"]
        else (
            "DIFFERENT: the cell's scenario was edited, or the code or a parameter file on disk "
            "changed since the cell started (the checksum covers them all)"
        )
    )
    print(f"report: {out} (checksum {st['checksum']}; the cell runs {running}: {same})")
    return 0 if running == st["checksum"] else 1


def _api(args: argparse.Namespace, method: str, path: str, params: dict | None = None,
         text: bool = False) -> Any:  # fmt: skip
    """One request to the REST service at ``args.api``; a refusal or no answer is an InputError
    naming the URL and the service's reason."""
    import urllib.error
    import urllib.parse
    import urllib.request

    from sara_app.errors import InputError

    url = args.api.rstrip("/") + path + ("?" + urllib.parse.urlencode(params) if params else "")
    req = urllib.request.Request(url, method=method)
    if args.token:
        req.add_header("Authorization", f"Bearer {args.token}")
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            body = r.read().decode()
    except urllib.error.HTTPError as e:
        raise InputError(f"{method} {url}: {e.code} {e.read().decode()[:300]}") from None
    except OSError as e:
        raise InputError(f"{method} {url}: no answer ({e}); is `sara-app serve` running?") from None
    return body if text else json.loads(body)


def register(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("report", help="evidence report of a cell (self-contained HTML, PDF)")
    r.add_argument("scenario", nargs="?", default=None,
                   help="a name in scenarios/ or a scenario file path (omitted: --cell's "
                   "running scenario, over the API)")  # fmt: skip
    r.add_argument("--out", default=None, help="HTML file (default: <scenario>-evidence.html)")
    r.add_argument("--pdf", default=None, help="also print it to this PDF (needs chromium)")
    r.add_argument("--json", default=None, help="also write the gathered evidence as JSON")
    r.add_argument("--recording", action="append", default=[],
                   help="a further recording to check containment on (repeatable)")  # fmt: skip
    r.add_argument("--modes", default="ssm,pfl,jssa", help="closed loops to run")
    r.add_argument("--duration", type=SECONDS, default=None,
                   help="seconds per closed loop (default: the scenario's)")  # fmt: skip
    r.add_argument("--episodes", type=whole(0), default=5, help="adversarial episodes per mode")
    r.add_argument("--audit", type=Path, default=None,
                   help="audit database (default: the dashboard's, if it exists)")  # fmt: skip
    r.add_argument("--cell", default=None,
                   help="a running cell: without a scenario, the report of the cell as it runs "
                   "(made by the API); with one, its audit rows are included and its checksum "
                   "compared with the file's")  # fmt: skip
    r.add_argument("--api", default=f"http://127.0.0.1:{API_PORT}",
                   help="the REST service of the running cells")  # fmt: skip
    r.add_argument("--token", default=None, help="an API token, where the service needs one")
    r.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    r.set_defaults(run=_report)
