"""Human-readable tables of a mission's figures (the demo's and review's output). Pure string formatting."""
from __future__ import annotations

import math
import numbers
import sys
import textwrap
from collections.abc import Mapping

from fusion.confirmation import CANDIDATE, candidate_clause

# a flagged map's split (fusion/split.py), by its decision, in a clause short enough for a live event line
_SPLIT_BRIEF = {
    "whole": "the parts agree, so it is used whole",
    "parts": "the parts disagree, so each is merged under its own alignment",
    "before": "only the part made before the gap aligns; the rest is left out",
    "after": "only the part made from the gap on aligns; the rest is left out",
    "none": "neither part aligns on its own, so it is left out",
}


def _fmt(value, spec: str = ".3f", missing: str = "-") -> str:
    """A figure, or ``missing`` when it is none (absent, null, not finite, or no number at all: a recording written
    by another version)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return missing
    if isinstance(value, numbers.Integral):   # JSON's integers are unbounded
        if spec == "d":
            return format(value, spec)
        if abs(value) > sys.float_info.max:
            return missing
        value = float(value)
    elif spec == "d" or not math.isfinite(value):
        return missing
    return format(value, spec)


def _count(value) -> int:
    """A count as recorded; 0 when it is absent or no count (another version's recording)."""
    return value if isinstance(value, int) and not isinstance(value, bool) else 0


def _table(rows: list[list[str]]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True)))
             for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return lines


def too_near_line(robot: str, frames: int) -> str:
    """What to say of a robot's frames that faced a surface nearer than its stereo head measures."""
    return (f"{robot}: {frames} frame{'s' if frames != 1 else ''} faced a surface nearer than the stereo head measures "
            "(most matches beyond its disparity range): no reading taken from "
            f"{'them' if frames != 1 else 'it'}, the filter only predicted")


def scales_text(figures: dict) -> str:
    """"odometry scales: distance 0.992 ± 0.006, turn 0.959 ± 0.010, " from a smoothing's figures (the wheel
    odometry's measured / true, estimated with the poses); "" when the figures have none."""
    scales, sd = figures.get("odometry_scales"), figures.get("odometry_scale_sd")
    if not scales or not sd:
        return ""
    return (f"odometry scales: distance {scales[0]:.3f} ± {sd[0]:.3f}, turn {scales[1]:.3f} ± {sd[1]:.3f}, ")


def smoothing_line(robot: str, figures: dict) -> str:
    """What a robot's smoothing after the mission did (runtime.mission's summary, robots[...]["smoothing"])."""
    if not figures.get("smoothed"):
        return f"{robot}: map not smoothed: {figures.get('reason')}; the filter's map is the one fused"
    keyframes = (f"{figures['frames']} keyframes of {figures['frames_seen']} frames, " if "frames_seen" in figures
                 else "")
    return (f"{robot}: map smoothed after the mission (the one fused): {keyframes}{figures['associated']} of "
            f"{figures['readings']} readings matched to it, {figures['cut']} cut, χ²/dof "
            f"{figures['chi2_per_dof']:.2f}, {scales_text(figures)}{figures['seconds']:.1f} s; the filter's map "
            f"beside it ({robot}-filter.npz)")


def format_summary(summary: dict) -> str:
    """The mission summary (as built by :class:`runtime.mission.Mission`) as aligned text tables."""
    clock = summary.get("clock")
    timing = f"{summary['duration']:.1f} s"
    if clock is not None:
        timing = (f"{summary['duration']:.1f} s {'simulated' if clock == 'simulated' else 'on the wall clock'} "
                  f"(wall {_fmt(summary.get('wall_seconds'), '.1f')} s, "
                  f"{_fmt(summary.get('realtime_factor'), '.2f')}x real time)")
    lines = [f"Mission: {len(summary['robots'])} robot(s), {timing}, camera {summary['camera']}, "
             f"{summary['particles']} particles, seed {summary['seed']}", ""]
    stages = sorted({k for r in summary["robots"].values() for k in r["ms_per_frame"]})
    late = any(r.get("frames_late") is not None for r in summary["robots"].values())  # virtual heads only
    rows = [["robot", "landmarks", "frames", "dropped"] + (["late"] if late else [])
            + ["final pose err (m)", "odometry err (m)"] + [f"{s} ms" for s in stages]]
    for name, r in summary["robots"].items():
        rows.append([name, str(r["landmarks"]), str(r["frames_processed"]),
                     str(r["frames_dropped"] + r["frames_without_odometry"])]
                    + ([_fmt(r.get("frames_late"), "d")] if late else [])
                    + [_fmt(r["final_position_error"]), _fmt(r.get("odometry_position_error"))]
                    + [_fmt(r["ms_per_frame"].get(s), ".1f") for s in stages])
    lines += _table(rows)
    drops = {name: r.get("frames_dropped_at_head") for name, r in summary["robots"].items()
             if r.get("frames_dropped_at_head")}
    for name, reasons in drops.items():
        because = "; ".join(f"{n} frames: {why}" for why, n in reasons.items())
        lines.append(f"{name}: the virtual head dropped {because}")
    for name, r in summary["robots"].items():
        if r.get("frames_too_near"):
            lines += _wrapped(too_near_line(name, r["frames_too_near"]))
    for name, r in summary["robots"].items():   # --smooth
        if r.get("smoothing"):
            lines += _wrapped(smoothing_line(name, r["smoothing"]))
    failures = summary.get("failures") or []
    if failures:
        lines += ["", "FAILED stages (the mission was stopped):"]
        lines += _table([["robot", "stage", "t (s)", "error"]]
                        + [[f["robot"], f["stage"], _fmt(f["t"], ".2f"), f["error"]] for f in failures])
    fusion = summary.get("fusion")
    lines.append("")
    if not fusion or not fusion["pairs"]:
        lines += _wrapped(no_fusion_text(summary["robots"], failures))
    else:
        # 1σ: the alignment's uncertainty against the true start frames (each map's own frame error included),
        # beside the error when the truth is known, so a reader sees whether the claim covers the error; none for a
        # split map's part made after its gap (the line below the table gives its own alignment's 1σ and why)
        rows = [["alignment", "found", "tx (m)", "ty (m)", "θ (rad)", "supports", "needed", "P(chance)", "common",
                 "1σ xy (m)", "1σ θ (rad)", "error xy (m)", "error θ (rad)"]]
        for p in fusion["pairs"]:
            rows.append([f"{p['other']} -> {p['reference']}", "yes" if p["aligned"] else "no",
                         _fmt(p["tx"]), _fmt(p["ty"]), _fmt(p["theta"], ".4f"), str(p["supports"]),
                         _fmt(p.get("required_supports"), "d"), _fmt(p.get("false_alarm_probability"), ".1e"),
                         str(p["common"]), _fmt(p.get("start_sigma_xy")), _fmt(p.get("start_sigma_theta"), ".4f"),
                         _fmt(p["error_xy"]), _fmt(p["error_theta"], ".4f")])
        lines += _table(rows)
        for p in fusion["pairs"]:
            if p["aligned"] and p.get("low_confidence"):
                lines.append(f"warning: {p['other']} -> {p['reference']} is a low-confidence alignment "
                             f"(P(chance) {_fmt(p.get('false_alarm_probability'), '.1e')}): check it before use")
            elif not p["aligned"] and p.get("note") and p["note"] not in p.get("self_check", ""):
                lines += _wrapped(f"{p['other']} -> {p['reference']}: not aligned: {p['note']}")
            if p["aligned"] and _words(p.get("start_sigma_not_comparable")):   # a split map's part after its gap
                lines += _wrapped(f"{p['other']} -> {p['reference']}: "
                                  + "; ".join(t for t in (sigma_text(p), not_comparable_text(p)) if t))
            elif p["aligned"] and _words(p.get("error_not_comparable")):
                lines += _wrapped(f"{p['other']} -> {p['reference']}: {not_comparable_text(p)}")
            if p.get("self_check"):   # a map that flagged itself, split at the alarm (fusion/split.py)
                lines += _wrapped(f"{p['other']} -> {p['reference']}: {p['self_check']}")
            if p["aligned"] and (backed := prior_backed_warning(p)):
                lines += _wrapped(backed)
        lines.append("")
        lines.append(f"Merged map: {fusion['merged_landmarks']} landmarks "
                     f"(fusion took {_fmt(summary.get('fusion_ms'), '.1f')} ms; "
                     f"{summary.get('fusions_during_mission', 0)} fusion(s) during the mission)")
    return "\n".join(lines)


def no_fusion_text(robots: Mapping, failures: list | None = None) -> str:
    """The summary's fusion line when the mission ended with no alignment to show, saying why from the robots' maps:
    'Fusion: no alignment: every map is empty (robot1: 0 landmarks from 1 frame; robot2: 0 landmarks from 0
    frames).' (a loaded machine whose heads dropped nearly every frame), not "fewer than two maps" beside two."""
    if len(robots) < 2:
        return "Fusion: fewer than two maps, nothing to fuse."

    def held(name: str, r: Mapping) -> str:
        frames = r.get("frames_processed")
        return f"{name}: {r.get('landmarks', 0)} landmarks" + (
            "" if frames is None else f" from {frames} frame{'' if frames == 1 else 's'}")

    counts = "; ".join(held(name, r) for name, r in robots.items())
    mapped = [name for name, r in robots.items() if r.get("landmarks")]
    if not mapped:
        return f"Fusion: no alignment: every map is empty ({counts})."
    if len(mapped) == 1:
        return f"Fusion: no alignment: only {mapped[0]}'s map holds landmarks ({counts})."
    if any(f.get("stage") == "fusion" for f in failures or []):
        return f"Fusion: no alignment: the fusion failed (FAILED stages above; {counts})."
    return f"Fusion: no fusion was made ({counts})."


def _wrapped(sentence: str, width: int = 118) -> list[str]:
    """A long reason as lines of at most ``width`` characters, the continuation indented."""
    return textwrap.wrap(sentence, width, subsequent_indent="    ", break_on_hyphens=False) or [sentence]


def _words(value) -> str:
    """A recorded sentence on one line; "" when it is none (absent, empty, or not text: another version's recording)."""
    return " ".join(value.split()) if isinstance(value, str) else ""


def sigma_text(pair: Mapping, missing: str = "-") -> str:
    """'1σ 0.457 m / 0.0632 rad' (against the true start frames); for a placement of a split map's part made after
    its gap, whose start-frame 1σ the gap broke (fusion/split.py): '1σ 0.082 m / 0.0155 rad of the part's own
    alignment, none against the start frames', with the reason unless the error's clause gives the same one;
    "" when the pair carries neither."""
    why = _words(pair.get("start_sigma_not_comparable"))
    if why:
        text = ("no 1σ against the start frames" if pair.get("sigma_xy") is None else
                f"1σ {_fmt(pair.get('sigma_xy'), '.3f', missing)} m / {_fmt(pair.get('sigma_theta'), '.4f', missing)}"
                " rad of the part's own alignment, none against the start frames")
        return text if why == _words(pair.get("error_not_comparable")) else f"{text} ({why})"
    if pair.get("start_sigma_xy") is None:
        return ""
    return (f"1σ {_fmt(pair.get('start_sigma_xy'), '.3f', missing)} m / "
            f"{_fmt(pair.get('start_sigma_theta'), '.4f', missing)} rad")


def prior_backed_warning(pair: Mapping) -> str:
    """'warning: robot2 -> robot1 rests on the start prior: the maps alone are ambiguous (…);
    if the prior is wrong, so is this alignment' for an aligned pair (a ``PairResult.as_dict()``) that the maps' own
    evidence would not find (fusion.Alignment.prior_backing); "" otherwise."""
    why = _words(pair.get("prior_backed"))
    if not why:
        return ""
    what = f"{pair.get('other', '?')} -> {pair.get('reference', '?')}"
    return f"warning: {rests_on_prior_text(what, why)}"


def rests_on_prior_text(what: str, backing: str) -> str:
    """'<what> rests on the start prior: <why the maps alone do not decide it>; if the prior is wrong, so is this
    alignment', from ``backing``, an alignment's sentence 'found with the prior: …' (fusion.Alignment.prior_backing);
    the words of every warning of a prior-backed alignment (p3at fuse, the mission's summary)."""
    return (f"{what} rests on the start prior: {backing.partition(': ')[2] or backing}; if the prior is wrong, so is "
            "this alignment")


def not_comparable_text(pair: Mapping) -> str:
    """'error against the truth not comparable: the part after robot2's gap at t≈13.8 s does not share robot2's
    start' for an aligned pair placed by a split map's part that lacks its start (fusion/split.py); "" otherwise."""
    why = _words(pair.get("error_not_comparable"))
    return f"error against the truth not comparable: {why}" if why else ""


def split_brief(pair: Mapping) -> str:
    """A flagged map's split decision in one short clause ("" when neither map of the pair flagged itself); the
    full sentence, with each part's reason, is ``pair["self_check"]``."""
    decision, sentence = pair.get("split_decision"), pair.get("self_check")
    if not isinstance(decision, str) or decision not in _SPLIT_BRIEF:
        return ""
    sentence = sentence if isinstance(sentence, str) else ""
    who = sentence.split(" flagged itself", 1)[0] if " flagged itself" in sentence else "a map"
    brief = _SPLIT_BRIEF[decision]
    if decision == "none" and f"{CANDIDATE}: " in sentence:     # a part found once, not yet confirmed (live fusion)
        brief = "neither part is aligned yet (a part's alignment is a candidate, not yet confirmed), so it is left out"
    return f"{who} flagged itself and was split at its alarm: {brief}"


def not_aligned_reason(pair: Mapping) -> str:
    """Why a pair (a ``PairResult.as_dict()``) was not aligned, in one short clause: its supports against the
    number these maps need, with the chance of that many by accident, when that decided; else the fusion's note."""
    supports, needed = _count(pair.get("supports")), _count(pair.get("required_supports"))
    note = _words(pair.get("note"))  # one line, whatever the note holds
    if needed and supports < needed:
        why = f"{supports} supports, {needed} needed"
        chance = _fmt(pair.get("false_alarm_probability"), ".1e", "")
        if chance:
            why += f" (P(chance) {chance})"
        repeat, rival = _count(pair.get("self_repeat_supports")), _count(pair.get("second_best_supports"))
        if note.startswith("ambiguous") and repeat > rival:  # a map's own repeat set the number needed, not a rival
            why += f"; ambiguous: one map repeats itself under a distinct transform with {repeat} supports"
        elif note.startswith("ambiguous"):  # the second-best transform, not decoys, set the number needed
            why += f"; ambiguous: a distinct transform gathers {rival} supports"
        if note.startswith("the maps' best alignment contradicts the prior"):   # fusion/prior.py
            why += "; the best alignment contradicts the start prior"
        return why
    return note or "no reason given"


def candidate_text(pair: Mapping) -> str | None:
    """'robot2 -> robot1 is a candidate, not yet found (26 supports at (…); why)' for a pair (a
    ``PairResult.as_dict()``) found once and not yet confirmed (fusion/confirmation.py); None for any other pair."""
    candidate = candidate_clause(pair.get("note") or "")
    if pair.get("aligned", True) or candidate is None:
        return None
    return f"{pair['other']} -> {pair['reference']} is a candidate, not yet found ({candidate})"


def alignment_text(pair: Mapping, *, markdown: bool = False, missing: str = "-") -> str:
    """One pair's state after a fusion (a ``PairResult.as_dict()``, as recorded), in the words of both the
    recording's fusion status (Markdown, :func:`alignment_status`) and ``p3at review`` (plain text; a figure a
    recording lacks shows as ``missing``): aligned and what the claim rests on -- the supports against the number
    these maps need, the chance of that many by accident, the 1-σ of the alignment beside its error against the
    truth where that is known --, not yet aligned (a candidate), or not aligned and why."""
    def strong(word: str) -> str:
        return f"**{word}**" if markdown else word

    split = split_brief(pair)
    note = pair.get("note")
    candidate = candidate_clause(note) if isinstance(note, str) and not pair.get("aligned", True) else None
    if candidate is not None:   # found once, not yet confirmed (fusion/confirmation.py)
        return (f"{strong('not yet aligned')}: a candidate, not yet found ({candidate})"
                + (f"; {split}" if split else ""))
    if not pair.get("aligned", True):
        return f"{strong('not aligned')}: {split or not_aligned_reason(pair)}"
    needed, chance = pair.get("required_supports"), pair.get("false_alarm_probability")
    text = (f"{strong('aligned')}: tx {_fmt(pair.get('tx'), '.3f', missing)} m, "
            f"ty {_fmt(pair.get('ty'), '.3f', missing)} m, θ {_fmt(pair.get('theta'), '.4f', missing)} rad; "
            f"{_fmt(pair.get('supports'), 'd', missing)} supports")
    if _count(needed):
        text += f" ({needed} needed" + (f", P(chance) {_fmt(chance, '.1e', missing)}" if chance is not None
                                        else "") + ")"
    text += f", {_fmt(pair.get('common'), 'd', missing)} common landmarks"
    sigma = sigma_text(pair, missing)
    if sigma:
        text += f"; {sigma}"
    if pair.get("error_xy") is not None:
        text += (f"; error against the truth {_fmt(pair.get('error_xy'), '.3f', missing)} m / "
                 f"{_fmt(pair.get('error_theta'), '.4f', missing)} rad")
    elif why := not_comparable_text(pair):
        text += f"; {why}"
    if pair.get("low_confidence"):
        text += f"; {strong('low confidence') if markdown else 'LOW CONFIDENCE'}: check it before use"
    if backed := _words(pair.get("prior_backed")):   # the maps alone would not find it (fusion.Alignment.prior_backing)
        head, _, rest = backed.partition(": ")
        text += f"; {strong(head) if markdown else head.upper()}: {rest} -- only as right as the start prior"
    return text + (f"; {split}" if split else "")


def alignment_status(t: float, pair: Mapping) -> str:
    """One pair's last fusion (a ``PairResult.as_dict()``) as a Markdown paragraph for the recording's fusion status
    (runtime/rerun_log.py, ``fusion/status``): :func:`alignment_text` at the time the viewer shows."""
    return f"**{pair.get('other', '?')} → {pair.get('reference', '?')}** (fusion at t = {t:.0f} s): " + \
        alignment_text(pair, markdown=True)


def start_prior_line(reference: str, other: str, prior) -> str:
    """The mission's and the fusion node's line, said once per pair, that its fusion uses a start prior
    (``fusion.prior.StartPrior`` of ``other``'s start in ``reference``'s frame)."""
    return f"fusion uses a start prior for {other} in {reference}'s frame: {prior.text()}"


def fusion_event_line(t: float, pair) -> str:
    """The mission's and the fusion node's event line for one pair (a ``PairResult`` or its ``as_dict()``)."""
    p = pair if isinstance(pair, Mapping) else pair.as_dict()
    candidate = candidate_text(p)
    if candidate is not None:
        return f"fusion at t={t:.0f}s: {candidate}"
    if not p["aligned"]:
        why = split_brief(p) or not_aligned_reason(p)   # a split's parts' reasons are in the summary, not live
        return f"fusion at t={t:.0f}s: {p['other']} does not overlap {p['reference']} yet: {why}"
    line = f"fusion at t={t:.0f}s: {p['other']} -> {p['reference']} ({p['supports']} supports, {p['common']} common)"
    if p.get("error_xy") is not None:
        line += f", error {p['error_xy']:.3f} m / {p['error_theta']:.4f} rad"
    elif why := not_comparable_text(p):
        line += f", {why}"
    if backed := _words(p.get("prior_backed")):     # the maps alone would not find it: said short, live
        line += f", {backed.split(' (', 1)[0]}"
    return line


def fusion_progress_part(pair) -> str:
    """The fusion's part of the mission's and the fleet's progress line, for the last fusion's first pair (a
    ``PairResult``): its error against the truth where the maps carry it, "aligned" where they do not (real robots,
    a split map's part made after its gap), else "no alignment" (a candidate is not yet an alignment)."""
    if not pair.aligned:
        return "fusion: no alignment"
    if pair.error_xy is not None:
        return f"fusion: error {pair.error_xy:.2f} m"
    return f"fusion: aligned ({pair.supports} supports)"
