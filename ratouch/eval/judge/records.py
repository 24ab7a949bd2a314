"""TVL judge data: the 1-10 score range, the result-file format and its checks, GPT-4's score.

A TVL-format result file is a JSON list of objects with a ``label`` (the ground-truth
adjectives), a ``generated response`` (a string or null) and, in TVL's published files, GPT-4's
``evaluation`` (its score first) and the ``image_fp`` that names the subset (SSVTP or HCT).
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from ratouch.errors import DataError, DataNotFoundError
from ratouch.vocabulary import parse_adjectives

MIN_SCORE, MAX_SCORE = 1.0, 10.0
LABEL_KEY, RESPONSE_KEY, EVAL_KEY = "label", "generated response", "evaluation"
SUBSETS = ("SSVTP", "HCT")

# --------------------------------------------------------------------------- parsing

_SCORE_RE = re.compile(r"^\s*(?:\*\*)?\s*(?:score\s*[:=]?\s*)?(\d{1,2}(?:\.\d+)?)(?!\d)", re.I)


def parse_gpt_score(evaluation: str | None) -> float | None:
    """The judge's score: the number (1-10) that starts its answer, else None.

    TVL's GPT-4 evaluations put the score first ("7.5\\nThe assistant's response ..."); scores
    may be fractional (7.5, 7.785), so the value is a float, as in TVL's own analysis script.
    A leading "Score:" or markdown bold and a trailing "/10" are tolerated.
    """
    if not isinstance(evaluation, str):
        return None
    m = _SCORE_RE.match(evaluation)
    if m is None:
        return None
    value = float(m.group(1))
    return value if MIN_SCORE <= value <= MAX_SCORE else None



def subset_of(image_fp: object) -> str | None:
    """"SSVTP" or "HCT" from a TVL image path (relative or absolute), else None."""
    if not isinstance(image_fp, str):
        return None
    fp = image_fp.lower()
    if "ssvtp" in fp:
        return "SSVTP"
    if "hct" in fp:
        return "HCT"
    return None


def check_records(records: object, source: str = "input") -> list[dict]:
    """Raise DataError unless `records` is a non-empty list of objects, each with a non-empty
    string ``label`` and a ``generated response`` (a string or null)."""
    if not isinstance(records, list):
        raise DataError(f"{source}: expected a JSON list of objects, got {type(records).__name__}")
    if not records:
        raise DataError(f"{source}: the list is empty")
    for i, rec in enumerate(records):
        if not isinstance(rec, dict):
            raise DataError(f"{source}: record {i} is a {type(rec).__name__}, not an object")
        for key in (LABEL_KEY, RESPONSE_KEY):
            if key not in rec:
                raise DataError(f"{source}: record {i} has no {key!r} key")
        if not isinstance(rec[LABEL_KEY], str) or not parse_adjectives(rec[LABEL_KEY]):
            raise DataError(f"{source}: record {i} has an empty or non-string label "
                            f"{rec[LABEL_KEY]!r}")
        if rec[RESPONSE_KEY] is not None and not isinstance(rec[RESPONSE_KEY], str):
            raise DataError(f"{source}: record {i} 'generated response' must be a string or null, "
                            f"got {type(rec[RESPONSE_KEY]).__name__}")
    return records


def read_records(path: str | os.PathLike) -> list[dict]:
    """Load and check a TVL-format result file (see `check_records`)."""
    path = Path(path)
    if not path.is_file():
        raise DataNotFoundError(f"{path} does not exist or is not a file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as e:
        raise DataError(f"{path} is not valid JSON: {e}") from e
    return check_records(data, str(path))
