"""The progress line's fusion part (runtime.report.fusion_progress_part, used by the mission and the fleet): an
aligned pair whose error cannot be given (real robots carry no truth; a split map's part made after its gap does not
share the start) reads "aligned", never "no alignment" (it did until session 26)."""
from runtime.fusion_report import PairResult
from runtime.report import fusion_progress_part


def test_aligned_without_a_truth_reads_aligned():
    pair = PairResult("robot1", "robot2", aligned=True, tx=1.0, ty=0.0, theta=0.1, supports=42)
    assert fusion_progress_part(pair) == "fusion: aligned (42 supports)"


def test_aligned_with_a_truth_gives_its_error():
    pair = PairResult("robot1", "robot2", aligned=True, supports=42, error_xy=0.0251, error_theta=0.0034)
    assert fusion_progress_part(pair) == "fusion: error 0.03 m"


def test_not_aligned_and_candidates_read_no_alignment():
    assert fusion_progress_part(PairResult("robot1", "robot2", aligned=False)) == "fusion: no alignment"
