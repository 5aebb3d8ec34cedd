"""``p3at features --help`` says which pairs --virtual-head takes (session 48, D): it said "pairs from 'p3at camera
grab --mock'", whose pairs are raw (distorted) unless --rectify is given, and the command cannot tell: a raw pair
given as rectified ran without a word. --descriptor had no help at all."""
from __future__ import annotations

import pytest

from runtime.cli import main


def test_features_help_names_the_rectified_grab_and_the_descriptors(capsys):
    with pytest.raises(SystemExit):
        main(["features", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "'p3at camera grab --mock --rectify'" in text
    assert "--calib mocks/stereo_head/data/sth_mdcs2_default.ini" in text
    assert "corner descriptor: usurf" in text
