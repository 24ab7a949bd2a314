"""The stress sweeps: the knobs, the values each is swept over (mildest first), how a knob is
paired with its reference, and which test samples a sweep renders.
"""

from __future__ import annotations

from typing import Mapping, Sequence

from ratouch.errors import ConfigError
from ratouch.world.config import WorldConfig
from ratouch.world.sampler import TEST_SIZE, TEST_STRUCTURED

# knobs whose fixed value replaces a per-sample random draw (see "Pairing" in the package
# docstring)
PER_SAMPLE = ("object_scale", "clutter", "background_dominance", "tactile_noise", "tactile_blur")
# knobs that add a draw when set (box_offset > 0 draws the shift's direction): the paired
# reference sets them to a value that takes the draw but changes nothing (a 1e-6 box shift
# rounds to the unshifted box)
PAIR_FIXED = {"box_offset": 1e-6}
# the paper's failure case: a small object in a loud, cluttered scene
PAPER_FAILURE = {"object_scale": 0.12, "background_dominance": 1.0, "clutter": 4}
# mildest first; the unperturbed reference is added in front of each sweep
SWEEPS: dict[str, list[dict]] = {
    "object_scale": [{"object_scale": v} for v in (0.6, 0.35, 0.2, 0.12)],
    "clutter": [{"clutter": v} for v in (0, 2, 4, 8)],
    "background_dominance": [{"background_dominance": v} for v in (0.0, 0.5, 0.8, 1.0)],
    "tactile_noise": [{"tactile_noise": v} for v in (0.05, 0.1, 0.2)],
    "tactile_blur": [{"tactile_blur": v} for v in (2.0, 4.0, 6.0)],
    "tactile_rotation": [{"tactile_rotation": v} for v in (45.0, 90.0, 180.0)],
    "box_offset": [{"box_offset": v} for v in (0.25, 0.5, 1.0, 2.0)],
    "missing": [{"missing": "tactile"}],
    "paper_failure": [dict(PAPER_FAILURE)],
}
KNOBS = tuple(SWEEPS)
DEFAULT_N = 200


def _knob_value(knob: str, text: str):
    if knob == "missing":
        return text
    try:
        return int(text) if knob == "clutter" else float(text)
    except ValueError as e:
        raise ConfigError(f"{knob} value {text!r} is not a number") from e


def build_sweeps(knobs: Sequence[str] | None = None,
                 values: Mapping[str, Sequence] | None = None) -> dict[str, list[dict]]:
    """The sweeps to run: the chosen knobs (default all), optionally with other values.

    Every value is checked against the world's ranges here, before any work.
    """
    names = list(knobs) if knobs else list(KNOBS)
    values = dict(values or {})
    unknown = [k for k in list(names) + list(values) if k not in SWEEPS]
    if unknown:
        raise ConfigError(f"unknown stress knob(s) {sorted(set(unknown))}; known: "
                          f"{', '.join(KNOBS)}")
    if len(set(names)) != len(names):
        raise ConfigError(f"knob listed twice in {names}")
    stray = [k for k in values if k not in names]
    if stray:
        raise ConfigError(f"values given for {stray}, which are not among the knobs {names}")
    if "paper_failure" in values:
        raise ConfigError("paper_failure is one fixed combined point; it takes no values")
    sweeps = {}
    for knob in names:
        if knob in values:
            vals = list(values[knob])
            if not vals:
                raise ConfigError(f"no values given for {knob}")
            sweeps[knob] = [{knob: _knob_value(knob, str(v))} for v in vals]
        else:
            sweeps[knob] = [dict(p) for p in SWEEPS[knob]]
    for points in sweeps.values():
        for p in points:
            if p.get("missing") == "none":
                raise ConfigError("missing=none is the reference; sweep 'tactile' or 'visual'")
            WorldConfig().with_stress(**p)  # range checks (ConfigError)
    return sweeps


def parse_values(specs: Sequence[str] | None) -> dict[str, list[str]]:
    """`["tactile_noise=0.1,0.2", ...]` -> {"tactile_noise": ["0.1", "0.2"]}."""
    out: dict[str, list[str]] = {}
    for spec in specs or ():
        knob, sep, rest = spec.partition("=")
        if not sep or not rest.strip():
            raise ConfigError(f"--values {spec!r} must read KNOB=V1,V2,...")
        out[knob.strip()] = [v.strip() for v in rest.split(",") if v.strip()]
    return out


def stratified_indices(n: int | None, total: int | None = None,
                       structured: int | None = None) -> list[int]:
    """`n` test indices, evenly spaced within the structured and the wild subset, in
    proportion to their sizes (all of them when n is None or >= the split size)."""

    total = TEST_SIZE if total is None else total
    structured = TEST_STRUCTURED if structured is None else structured
    if n is None or n >= total:
        return list(range(total))
    if n < 2:
        raise ConfigError(f"--n {n}: at least 2 samples are needed")
    n_s = max(1, round(n * structured / total))
    n_w = n - n_s

    def spread(lo: int, hi: int, m: int) -> list[int]:
        return [lo + int(j * (hi - lo) / m) for j in range(m)]

    return spread(0, structured, n_s) + spread(structured, total, n_w)
