"""benchmarks/mrclam_constellation's ``--rival-rounds``: session 29's options (--fewer-rival, --distinct-points) in
the first rounds only. The options themselves are :func:`estimation.pass_matching.judge_passes`'
(tests/estimation/test_pass_matching.py)."""
from __future__ import annotations


def test_rival_rounds_keeps_the_options_in_the_first_rounds_only():
    from types import SimpleNamespace

    from benchmarks.mrclam_constellation import rival_options
    args = SimpleNamespace(fewer_rival=True, distinct_points=False, rival_rounds=1)
    assert rival_options(args, 1) == {"fewer_rival": True, "distinct_points": False}
    assert rival_options(args, 2) == {"fewer_rival": False, "distinct_points": False}
    every = SimpleNamespace(fewer_rival=True, distinct_points=True, rival_rounds=None)
    assert rival_options(every, 9) == {"fewer_rival": True, "distinct_points": True}


def test_rival_rounds_without_a_rival_option_is_refused(capsys):
    import pytest

    from benchmarks.mrclam_constellation import main
    with pytest.raises(SystemExit):
        main(["--rival-rounds", "1"])
    assert "--rival-rounds needs --fewer-rival" in capsys.readouterr().err
