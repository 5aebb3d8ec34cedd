"""A map's own verdict on itself, ``metadata["self_check"]`` (estimation/fastslam/self_check.py): did the map
lose its place (old landmarks predicted in view and not re-detected, a CUSUM over frames)? Written by FastSLAM with
every map it exports (``FastSLAM.best_map``); read by ``p3at fuse`` (a warning line per map that flagged itself,
``--json`` key ``self_check``) and the Rerun log. Maps written before the key existed load without it.
"""
from __future__ import annotations

import math

from estimation.fastslam.self_check import KEY

ALARM_FIELDS = ("t", "since", "statistic", "frames", "predicted", "redetected", "expected")
NUMBER_FIELDS = ("threshold", "false_alarm_per_frame", "dispersion", "statistic", "max_statistic", "frames",
                 "frames_tested", "predicted", "redetected", "expected", "n_alarms")
MAX_ALARMS_READ = 100   # a hostile file's list is cut: the verdict's figures stay bounded


def _number(value, where: str) -> float:
    # finite: an Infinity would be printed by `p3at fuse --json` as Infinity, which strict JSON readers (jq) refuse;
    # an integer of hundreds of digits is one too (float() of it raises OverflowError)
    try:
        number = math.nan if isinstance(value, bool) or not isinstance(value, int | float) else float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise ValueError(f"metadata {KEY}.{where} must be a finite number, not {value!r:.40}")
    return number


def read_self_check(metadata: dict) -> dict | None:
    """A map's self-check verdict (lost, alarms, threshold and totals); None if it carries none (an older map, a
    merged one). ValueError naming the field if the key is there but malformed (reprs cut: one line)."""
    verdict = metadata.get(KEY)
    if verdict is None:
        return None
    if not isinstance(verdict, dict):
        raise ValueError(f"metadata {KEY} must be a mapping, not {verdict!r:.80}")
    if not isinstance(verdict.get("lost"), bool):
        raise ValueError(f"metadata {KEY}.lost must be true or false, not {verdict.get('lost')!r:.40}")
    alarms = verdict.get("alarms")
    if not isinstance(alarms, list):
        raise ValueError(f"metadata {KEY}.alarms must be a list, not {alarms!r:.80}")
    out = {"lost": verdict["lost"]}
    for name in NUMBER_FIELDS:
        out[name] = _number(verdict.get(name), name)
    out["alarms"] = []
    for i, alarm in enumerate(alarms[:MAX_ALARMS_READ]):
        if not isinstance(alarm, dict):
            raise ValueError(f"metadata {KEY}.alarms[{i}] must be a mapping, not {alarm!r:.80}")
        out["alarms"].append({name: _number(alarm.get(name), f"alarms[{i}].{name}") for name in ALARM_FIELDS})
    if out["lost"] and not out["alarms"]:
        raise ValueError(f"metadata {KEY} says the map lost its place but lists no alarm")
    return out


def lost_text(verdict: dict) -> str | None:
    """'may have lost its place at t≈45.5 s: 5 of 85 old landmarks predicted in view re-detected since 35.9 s,
    33.4 expected (CUSUM 22.5 ≥ 11.5); 2 more alarms after it', or None for a map that holds. "May": the test's
    stated false-alarm rate does not hold on the rendered building (it flags some healthy maps, docs/fastslam-history.md
    "Session 7: self-check"), so the text states what was seen, not the rate."""
    if not verdict["lost"]:
        return None
    a = verdict["alarms"][0]
    more = verdict["n_alarms"] - 1
    return (f"may have lost its place at t≈{a['t']:.1f} s: {a['redetected']:.0f} of {a['predicted']:.0f} old "
            f"landmarks predicted in view re-detected since {a['since']:.1f} s, {a['expected']:.1f} expected (CUSUM "
            f"{a['statistic']:.1f} ≥ {verdict['threshold']:.1f})"
            + (f"; {more:.0f} more alarm{'s' if more != 1 else ''} after it" if more > 0 else ""))
