"""The command line's numeric options (sara_app.commands._numbers): every option of every
``sara-app`` command that takes a number checks it where it is given. Against a brute-force
oracle for the types, and over the real parser: no option takes a bare ``float`` or ``int``
(which let NaN, infinities and negative durations through to the commands), and every numeric
option refuses NaN and infinity with exit status 2, naming the option."""

from __future__ import annotations

import argparse
import math

import pytest

from sara_app.cli import build_parser, main
from sara_app.commands._numbers import COUNT, PORT, SECONDS, SEED, real, whole

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
