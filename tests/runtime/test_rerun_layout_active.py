"""A recording's layout is sent as the *active* blueprint, not only the default: a viewer keeps the layout it last
showed for the application id ``p3at-fusion`` (an earlier mission, a data set run), and a default waits behind it
until the user clicks "reset blueprint" -- ``make demo``'s recording opened in a viewer that had shown a data set run
came up as that run's two tabs. Read with Rerun's own ``rerun rrd print``."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.rerun_log import MissionLog
from runtime.rerun_sink import open_recording
from runtime.rerun_style import dataset_blueprint, mission_blueprint

from .rerun_helpers import ROBOTS


@pytest.mark.parametrize("layout", [mission_blueprint(ROBOTS), dataset_blueprint("robot2")])
def test_a_saved_recordings_layout_is_activated_when_opened(tmp_path, layout):
    rrd = tmp_path / "m.rrd"
    log = MissionLog(open_recording(str(rrd), blueprint=layout), ROBOTS, blueprint=False)
    log.log_scalars("robot1", 0.0, {"ess": 50.0}, 0)
    log.close()
    rerun = Path(sys.executable).with_name("rerun")
    printed = subprocess.run([str(rerun), "rrd", "print", str(rrd)], capture_output=True, text=True, timeout=300)
    assert printed.returncode == 0, printed.stderr
    commands = re.findall(r"BlueprintActivationCommand\(.*?make_active: (\w+), make_default: (\w+)\)", printed.stdout)
    assert commands and all(active == "true" for active, _ in commands), commands
