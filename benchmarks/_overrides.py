"""Command-line stage overrides shared by the benchmark scripts: a JSON object of one stage's config fields, checked
against the pipeline config before any work starts (an unknown field or a bad value ends the command naming the
flag)."""

from __future__ import annotations

import argparse
import json


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
