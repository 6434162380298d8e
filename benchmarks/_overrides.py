"""Command-line checks shared by the benchmark scripts: stage overrides (a JSON object of one stage's config fields,
checked against the pipeline config before any work starts: an unknown field or a bad value ends the command naming
the flag) and argparse types for numbers with a range."""

from __future__ import annotations

import argparse
import json
import math


def stage_overrides(ap: argparse.ArgumentParser, text: str | None, flag: str, stage: str) -> dict:
    """The overrides of ``stage``'s config given as JSON ``text`` with ``flag`` ({} when absent); ``ap.error`` if
    they are not a JSON object of valid fields."""
    if not text:
        return {}
    try:
        over = json.loads(text)
    except json.JSONDecodeError as e:
        ap.error(f"{flag}: not JSON ({e})")
    if not isinstance(over, dict):
        ap.error(f"{flag}: expected a JSON object of {stage} config fields")
    from service.config import PipelineConfig

    try:
        PipelineConfig.from_dict({stage: over})
    except (TypeError, ValueError) as e:
        ap.error(f"{flag}: {e}")
    return over


def off_or_float(text: str) -> float | str:
    """argparse type of the simulator flags: a finite number, or 'off' (Bullet's own default)."""
    if str(text).lower() == "off":
        return "off"
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or 'off', not {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number or 'off', not {text!r}")
    return v


def off_or_positive(text: str) -> float | str:
    """argparse type: a number > 0, or 'off'."""
    v = off_or_float(text)
    if v != "off" and not v > 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0 or 'off', not {text!r}")
    return v


def off_or_unit(text: str) -> float | str:
    """argparse type: a number in [0, 1] (an erp, a fraction), or 'off'."""
    v = off_or_float(text)
    if v != "off" and not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1] or 'off', not {text!r}")
    return v


def finite_float(text: str) -> float:
    """argparse type: a finite number."""
    return _ranged(text, lambda v: True, "a finite number")


def _ranged(text: str, ok, what: str, cast=float):
    try:
        v = cast(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, not {text!r}") from None
    if not (math.isfinite(v) and ok(v)):
        raise argparse.ArgumentTypeError(f"expected {what}, not {text!r}")
    return v


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    return _ranged(text, lambda v: v > 0, "a number > 0")


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    return _ranged(text, lambda v: v >= 0, "a number >= 0")


def unit_float(text: str) -> float:
    """argparse type: a number in [0, 1] (a coefficient of restitution, a fraction)."""
    return _ranged(text, lambda v: 0 <= v <= 1, "a number in [0, 1]")


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    return _ranged(text, lambda v: v >= 1, "an integer >= 1", int)
