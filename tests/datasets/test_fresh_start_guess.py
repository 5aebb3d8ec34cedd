"""estimation.fresh_start.names_guess on MRCLAM robot 2's first 120 s: a fresh start for smoothing a set of names,
from the known-ID filter with the names as identities (the barcodes only build the names here)."""
from __future__ import annotations

import numpy as np

from .test_constellation import _robot2


def test_the_guess_takes_names_as_labels_leaves_unnamed_sightings_out_and_fits_the_smoothers_frames():
    from estimation.fresh_start import names_guess
    from estimation.named_smoothing import named_problem
    log, noise, config, _ = _robot2(until=120.0)
    barcodes = np.asarray(log.landmark_ids, np.int64)
    posts = np.unique(barcodes)
    relabel = {int(p): 1000 + 7 * k for k, p in enumerate(posts[::-1])}     # other labels, another order
    names = np.array([relabel[int(b)] for b in barcodes])
    left_out = int(posts[0])
    names[barcodes == left_out] = -1
    poses, positions = names_guess(log, names, noise, config, np.random.default_rng(0))
    assert set(positions) == {relabel[int(p)] for p in posts if p != left_out}
    assert poses.shape == (len(named_problem(log, names, noise, config, path_step_s=0.25).frame_times) + 1, 3)
    same = np.where(barcodes == left_out, -1, barcodes)                    # the same partition, the barcodes' labels
    poses_b, positions_b = names_guess(log, same, noise, config, np.random.default_rng(0))
    np.testing.assert_allclose(poses, poses_b, rtol=0, atol=1e-6)   # the order of summation only
    for p in posts:
        if p != left_out:
            np.testing.assert_allclose(positions[relabel[int(p)]], positions_b[int(p)], rtol=0, atol=1e-6)
