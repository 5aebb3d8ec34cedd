"""Benchmarks that read the MRCLAM data set refuse an output folder inside it (benchmarks/output_paths.py): a user's
copy of the data set is their data. fusion_sim's own command line is tested in test_fusion_sim_cli.py."""
from __future__ import annotations

import pytest

from benchmarks import eval_mrclam, mrclam_nees_diagnosis, smoother_frame_diagnosis
from benchmarks.output_paths import output_refusal


def test_inside_is_the_folder_itself_or_below_it_after_resolving(tmp_path):
    """The commands' check (runtime.commands.options.check_output_apart), since session 24 the only one."""
    data = tmp_path / "data"
    data.mkdir()
    (tmp_path / "link").symlink_to(data, target_is_directory=True)
    for inside in (data, data / "maps", data / "a" / ".." / "b", tmp_path / "link" / "maps", tmp_path / "link"):
        assert output_refusal("s", "--out", inside, data) is not None, inside
    for outside in (tmp_path, tmp_path / "data-maps", tmp_path / "other", data / ".." / "maps"):
        assert output_refusal("s", "--out", outside, data) is None, outside


def test_the_refusal_is_one_line_naming_the_option_and_none_without_an_output(tmp_path):
    text = output_refusal("eval_mrclam", "--maps", tmp_path / "maps", tmp_path)
    assert text.startswith("eval_mrclam: error: --maps ") and "\n" not in text and "data set folder" in text
    assert output_refusal("eval_mrclam", "--maps", None, tmp_path) is None
    assert output_refusal("eval_mrclam", "--maps", tmp_path.parent / "elsewhere", tmp_path) is None


@pytest.mark.parametrize(("main", "option"), [(eval_mrclam.main, "--maps"), (mrclam_nees_diagnosis.main, "--dump"),
                                              (smoother_frame_diagnosis.main, "--cache")])
def test_each_script_refuses_before_it_writes(main, option, tmp_path, capsys):
    data = tmp_path / "copy-of-mrclam"
    data.mkdir()
    (data / "Barcodes.dat").write_text("# Subject #    Barcode #\n")
    before = sorted(data.rglob("*"))
    assert main(["--data", str(data), option, str(data / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{option} " in err and "inside the data set folder" in err
    assert sorted(data.rglob("*")) == before
