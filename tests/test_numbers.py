"""The command line's numeric options (sara_app.options): every option of every ``sara-app``
command and of the cell processes' own entry points (router, worker, controller, replayer, ROS 2
bridge, the worker's early start) that takes a number checks it where it is given. Against a
brute-force oracle for the types, and over the real parsers: no option takes a bare ``float``
or ``int`` (which let NaN, infinities and negative durations through to the commands), and
every numeric option refuses NaN and infinity with exit status 2, naming the option. The
example publisher (plain zenoh, no sara_app) checks its own."""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import pytest

from sara_app.cli import build_parser, main
from sara_app.options import COUNT, PORT, SECONDS, SEED, real, whole

_TEXTS = ["nan", "inf", "-inf", "", "x", "1e400", "-1", "0", "0.5", "1", "2", "65535", "65536",
          "1e3", " 3 ", "-0", "3.0"]  # fmt: skip


def _float_or_none(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


@pytest.mark.parametrize(
    "kw",
    [{}, {"low": 0.0}, {"above": 0.0}, {"low": 1.0}, {"low": 0.0, "high": 1.0},
     {"above": 0.0, "high": 1.0}],
)  # fmt: skip
def test_a_real_option_takes_exactly_the_finite_numbers_of_its_range(kw) -> None:
    parse = real(**kw)
    for text in _TEXTS:
        v = _float_or_none(text)
        ok = (v is not None and math.isfinite(v)
              and v >= kw.get("low", -math.inf) and v <= kw.get("high", math.inf)
              and ("above" not in kw or v > kw["above"]))  # fmt: skip
        if ok:
            assert parse(text) == v
        else:
            with pytest.raises(argparse.ArgumentTypeError, match=f"{text!r}; expected a finite"):
                parse(text)


@pytest.mark.parametrize("low, high", [(0, None), (1, None), (1, 65535)])
def test_a_whole_option_takes_exactly_the_integers_of_its_range(low, high) -> None:
    parse = whole(low, high)
    for text in _TEXTS:
        try:
            v: int | None = int(text)
        except ValueError:
            v = None
        if v is not None and v >= low and (high is None or v <= high):
            assert parse(text) == v
        else:
            with pytest.raises(argparse.ArgumentTypeError, match="expected a whole number"):
                parse(text)


def test_the_named_types() -> None:
    assert SECONDS("0.002") == 0.002 and COUNT("1") == 1 and SEED("0") == 0 and PORT("8080") == 8080
    for parse, text in ((SECONDS, "0"), (COUNT, "0"), (SEED, "-1"), (PORT, "0"), (PORT, "70000")):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(text)


def _numeric_options() -> list[tuple[str, str, object]]:
    """``(command, option, type)`` of every option of every ``sara-app`` command that is not a
    flag, a choice or a text."""
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    out = []
    for name, parser in sub.choices.items():
        for action in parser._actions:
            if action.option_strings and action.type is not None:
                out.append((name, action.option_strings[-1], action.type))
    return out


def test_no_option_takes_a_bare_float_or_int() -> None:
    options = _numeric_options()
    assert len(options) > 40  # the parser was walked
    bare = [(c, o) for c, o, t in options if t in (float, int)]
    assert bare == []


_CHECKED = [
    (c, o) for c, o, t in _numeric_options() if getattr(t, "__name__", "") in ("real", "whole")
]


@pytest.mark.parametrize("command, option", _CHECKED)
def test_every_numeric_option_refuses_nan_and_infinity(command, option, capsys) -> None:
    positional = {"reach": ["r.csv"], "volumes": ["r.csv"], "calibrate": ["r.csv"],
                  "legs": ["r.csv"], "displacement": ["r.csv"], "report": ["s"]}  # fmt: skip
    for text in ("nan", "inf"):
        with pytest.raises(SystemExit) as e:
            main([command, *positional.get(command, []), f"{option}={text}"])
        assert e.value.code == 2
        assert f"argument {option}" in capsys.readouterr().err


def _process_parsers() -> dict[str, argparse.ArgumentParser]:
    """The parsers of the processes ``serve`` starts (and an integrator may start alone)."""
    from sara_app.bus.process import process_parser
    from sara_app.bus.router import build_parser as router_parser
    from sara_app.processes.worker_start import early_parser

    return {"router": router_parser(), "worker": process_parser("worker", "", state=True),
            "worker_start": early_parser()}  # fmt: skip


def test_the_processes_take_no_bare_float_or_int() -> None:
    options = [(name, a.option_strings[-1], a.type) for name, p in _process_parsers().items()
               for a in p._actions if a.option_strings and a.type is not None]  # fmt: skip
    assert {(n, o) for n, o, _ in options} >= {("router", "--port"), ("worker", "--duration"),
                                                ("worker_start", "--rt-priority")}  # fmt: skip
    assert [(n, o) for n, o, t in options if t in (float, int)] == []


@pytest.mark.parametrize(
    "process, option, bad",
    [("router", "--port", "0"), ("router", "--rt-priority", "100"), ("worker", "--duration", "nan"),
     ("worker", "--duration", "-1"), ("worker", "--port", "inf"), ("worker", "--rt-priority", "x"),
     ("worker_start", "--rt-priority", "-1"), ("worker_start", "--port", "70000")],
)  # fmt: skip
def test_a_process_refuses_a_bad_number_naming_the_option(process, option, bad, capsys) -> None:
    with pytest.raises(SystemExit) as e:
        _process_parsers()[process].parse_args([f"{option}={bad}"])
    assert e.value.code == 2
    assert f"argument {option}: {bad!r}; expected a" in capsys.readouterr().err


def test_the_controller_process_refuses_nan_before_it_connects() -> None:
    """Through a real entry point: no router runs, so a check after connecting would say the
    router is missing instead."""
    out = subprocess.run([sys.executable, "-m", "sara_app.peers.controller", "--duration=nan"],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 2 and "argument --duration: 'nan'; expected a finite" in out.stderr


@pytest.mark.parametrize("option, bad", [("--rate", "0"), ("--rate", "nan"), ("--count", "-1")])
def test_the_example_publisher_refuses_a_bad_number(option, bad) -> None:
    """It divided by a rate of 0; it imports only zenoh, so it checks its own numbers."""
    path = Path(__file__).parents[1] / "sara_app" / "bus" / "example_publisher.py"
    out = subprocess.run([sys.executable, str(path), f"{option}={bad}"], capture_output=True,
                         text=True, timeout=60)  # fmt: skip
    assert out.returncode == 2 and f"argument {option}: {bad!r}; expected a" in out.stderr


@pytest.mark.parametrize("option, bad", [("--rate", "0"), ("--rate", "nan"), ("--count", "-1")])
def test_the_contracts_tracker_refuses_a_bad_number(option, bad, tmp_path) -> None:
    """The tracker CONTRACT.md shows, run as written, stops with a usage error naming it."""
    import re

    text = (Path(__file__).parents[1] / "sara_app" / "bus" / "CONTRACT.md").read_text()
    (script,) = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    (tmp_path / "tracker.py").write_text(script)
    out = subprocess.run([sys.executable, str(tmp_path / "tracker.py"), option, bad],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert out.returncode == 2 and f"{option} " in out.stderr.splitlines()[-1]
