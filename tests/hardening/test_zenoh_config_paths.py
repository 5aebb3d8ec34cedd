"""`--exchange zenoh:PATH` where PATH is a folder or a FIFO says what is there (session 25, C); it said 'no such Zenoh
configuration file' of a path that exists."""
from __future__ import annotations

import os

import pytest

from runtime.fleet.zenoh_exchange import ExchangeError, make_config


@pytest.mark.parametrize(("kind", "says"), [("folder", "a folder, not a Zenoh configuration file"),
                                            ("fifo", "not a regular file but a FIFO"),
                                            ("missing", "no such Zenoh configuration file")])
def test_a_config_path_that_is_no_file_is_named_for_what_it_is(tmp_path, kind, says) -> None:
    path = tmp_path / "zenoh.json5"
    if kind == "folder":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    with pytest.raises(ExchangeError) as info:
        make_config(str(path), "robot")
    assert str(info.value) == f"{path}: {says}" or str(info.value).startswith(f"{path}: {says}")
