"""A noise model's out-of-range value names its section, as a wrong type or an unknown key already did
("neg.toml: range_sigma_m must be a finite number >= 0" named no section; session 48's walkthrough of
docs/fastslam.md, "Noise models": errors name file and key)."""
from __future__ import annotations

import pytest

from estimation.noise_model import P3AT_VIDERE_DEFAULT, NoiseModel, NoiseModelError


@pytest.mark.parametrize(("section", "key", "value", "complaint"), [
    ("odometry", "xy_var_per_m", "-1.0", "[odometry] xy_var_per_m must be a finite number >= 0, not -1.0"),
    ("stereo", "sigma_d_px", "nan", "[stereo] sigma_d_px must be a finite number >= 0, not nan"),
])
def test_a_bad_value_names_file_section_and_key(tmp_path, section, key, value, complaint):
    good = tmp_path / "good.toml"
    P3AT_VIDERE_DEFAULT.save(good)
    lines = good.read_text().splitlines()
    start = lines.index(f"[{section}]")
    row = next(i for i in range(start, len(lines)) if lines[i].startswith(f"{key} ="))
    lines[row] = f"{key} = {value}"
    bad = tmp_path / "bad.toml"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(NoiseModelError) as e:
        NoiseModel.load(bad)
    assert str(e.value) == f"{bad}: {complaint}"
