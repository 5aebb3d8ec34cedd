"""``runtime.report.alignment_text`` words a recorded pair for both ``p3at review`` and the viewer's fusion status
(session 26, C). Review reads it from a recording another version (or anything) may have written: whatever JSON
the recorded fields hold, the text is one line, never an exception."""
from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from runtime.report import alignment_status, alignment_text

KEYS = ["reference", "other", "aligned", "tx", "ty", "theta", "supports", "required_supports",
        "false_alarm_probability", "common", "start_sigma_xy", "start_sigma_theta", "error_xy", "error_theta",
        "low_confidence", "note", "split_decision", "self_check", "self_repeat_supports", "second_best_supports"]
LEAF = st.one_of(st.none(), st.booleans(), st.integers(-10**30, 10**30), st.sampled_from([10**400, -(10**309)]),
                 st.floats(), st.text(max_size=12),
                 st.sampled_from(["whole", "parts", "before", "after", "none", "candidate: 3 supports at (x)",
                                  "ambiguous: x", "robot2 flagged itself at 3 s"]))
JSON = st.recursive(LEAF, lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner,
                                                                                      max_size=2), max_leaves=4)


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(KEYS), JSON))
def test_any_recorded_pair_is_worded_in_one_line(pair) -> None:
    for text in (alignment_text(pair, missing="?"), alignment_text(pair, markdown=True)):
        assert isinstance(text, str) and text and "\n" not in text, text
    assert alignment_status(12.0, pair).endswith(alignment_text(pair, markdown=True))
