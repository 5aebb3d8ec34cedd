"""The texts of a good calibration in each format a calibration file comes in (OpenCV YAML and XML, a camera_info
pair), for tests that damage them."""
from __future__ import annotations

from pathlib import Path

from drivers.videre import calibration as cal
from drivers.videre import camera_info
from mocks.stereo_head import default_calibration


def good_calibration_texts(folder: Path) -> dict[str, str]:
    """{"yaml", "xml", "left", "right"}: the mock head's calibration written into ``folder`` and read back as text."""
    cal.save(default_calibration(), folder / "good.yaml")
    cal.save(default_calibration(), folder / "good.xml")
    camera_info.write_pair(default_calibration(), folder / "ci")
    return {"yaml": (folder / "good.yaml").read_text(), "xml": (folder / "good.xml").read_text(),
            "left": (folder / "ci" / "left.yaml").read_text(), "right": (folder / "ci" / "right.yaml").read_text()}
