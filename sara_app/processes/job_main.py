"""Entry point of a background job (``python -m sara_app.processes.job_main KIND INPUT OUTPUT``),
run by :mod:`sara_app.ops.jobs`: ``whatif`` (:func:`sara_app.sim.whatif.compare`, JSON out) or
``report`` (the evidence report, HTML out, its evidence as JSON beside it). It first drops to the
lowest CPU priority, so that the live worker and controller always come first. Progress goes to
stderr as JSON lines ``{"progress": f, "what": text}``; a failure as ``{"error": text}`` and exit 1.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

NICENESS = 19
KINDS = ("whatif", "report")


def _say(fraction: float, what: str) -> None:
    print(json.dumps({"progress": round(fraction, 4), "what": what}), file=sys.stderr, flush=True)


def _run(kind: str, data: dict, out: Path) -> None:
    from sara_app.scenario import parse_scenario

    if kind == "whatif":
        from sara_app.sim.whatif import compare

        res = compare(parse_scenario(data["current"], "the scenario in force"),
                      parse_scenario(data["edited"], "the edited scenario"),
                      data.get("duration_s"), _say)  # fmt: skip
        out.write_text(json.dumps(res))
        return
    from sara_app.report.evidence import Settings, gather
    from sara_app.report.html import render

    s = data.get("settings", {})
    audit = s.get("audit_path")
    settings = Settings(s.get("recordings", ()), s.get("modes", ("ssm", "pfl", "jssa")),
                        s.get("duration_s"), int(s.get("episodes", 5)),
                        Path(audit) if audit else None, s.get("cell"),
                        s.get("source", "a scenario given to the report"))  # fmt: skip
    ev = gather(parse_scenario(data["scenario"], "the cell's scenario"), settings, _say)
    out.write_text(render(ev))
    out.with_suffix(".json").write_text(json.dumps(ev.to_dict()))


def main(argv: list[str]) -> int:
    os.nice(NICENESS)
    if len(argv) != 3 or argv[0] not in KINDS:
        print(json.dumps({"error": f"usage: KIND INPUT OUTPUT with KIND in {KINDS}"}),
              file=sys.stderr)  # fmt: skip
        return 2
    try:
        _run(argv[0], json.loads(Path(argv[1]).read_text()), Path(argv[2]))
    except Exception as e:  # noqa: BLE001 - reported to the job's owner, never silent
        print(json.dumps({"error": f"{type(e).__name__}: {e}"}), file=sys.stderr, flush=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
