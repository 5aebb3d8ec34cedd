"""A Ctrl-C while `p3at run` is still starting up is not lost (session 47, F).

`run` and `demo` import the mission (numpy, scipy, FastSLAM, fusion, Rerun) after the command line is read, a second
or more, with Python's own SIGINT handler in place. A Ctrl-C then raises KeyboardInterrupt wherever the import is;
when that is inside importlib's module-lock callback (a weakref callback), Python prints 'Exception ignored in:
<function _get_module_lock.<locals>.cb ...>' with a traceback and goes on: the mission then ran to its end, the
robot driving, the Ctrl-C lost (found by sending SIGINT 0.3 s after `p3at run` started). Now the stop signals are
noted from the command's first line until the mission takes them; one that came before the mission began ends the
command before any robot is connected (128 + the signal: 130 for Ctrl-C), writing nothing.

The test makes the Ctrl-C land where Python swallows it, every time: the process signals itself from a weakref
callback while the command sets up (os.kill checks for signals before it returns, so KeyboardInterrupt is raised
inside the callback, as inside importlib's).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

CTRL_C_IN_A_CALLBACK = """
import os, signal, sys, weakref
import runtime.mission_cli as mission_cli
from runtime.cli import main

setting_up = mission_cli.config_from_args

class Module: pass

def config_from_args(*args, **kwargs):
    module = Module()
    lock = weakref.ref(module, lambda ref: os.kill(os.getpid(), signal.SIGINT))  # as importlib's module lock
    del module
    return setting_up(*args, **kwargs)

mission_cli.config_from_args = config_from_args
sys.exit(main(sys.argv[1:]))
"""

# demo --processes opens its Zenoh exchange (importing zenoh) before it starts the robots: the Ctrl-C lands there
CTRL_C_IN_A_CALLBACK_PROCESSES = """
import os, signal, sys, weakref
import runtime.fleet.options as options
from runtime.cli import main

opening = options.open_exchange

class Module: pass

def open_exchange(*args, **kwargs):
    module = Module()
    lock = weakref.ref(module, lambda ref: os.kill(os.getpid(), signal.SIGINT))
    del module
    return opening(*args, **kwargs)

options.open_exchange = open_exchange
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("command", ["run", "demo"])
def test_a_ctrl_c_while_the_command_starts_ends_it_before_any_robot_moves(tmp_path, command):
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", CTRL_C_IN_A_CALLBACK, command, "--camera", "synthetic",
                           "--particles", "10", "--seconds", "30", "--rerun", "none", "--quiet", "--out", str(out)],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert "Exception ignored" not in done.stderr, done.stderr  # before: the Ctrl-C printed as ignored...
    assert done.returncode == 130, (done.returncode, done.stderr)  # ...and the mission ran its 30 s, exit 0
    assert not out.exists() or not list(out.glob("robot*"))  # no robot was set up: no map, no log
    assert done.stdout == ""


def test_a_ctrl_c_while_demo_processes_starts_ends_it_before_any_robot_process_starts(tmp_path):
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", CTRL_C_IN_A_CALLBACK_PROCESSES, "demo", "--processes",
                           "--particles", "10", "--seconds", "5", "--rerun", "none", "--quiet", "--out", str(out)],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert "Exception ignored" not in done.stderr, done.stderr
    assert done.returncode == 130, (done.returncode, done.stderr)  # before: the robots ran their 5 s, exit 0
    assert not out.exists() or not list(out.glob("robot*"))  # no robot process started
    assert done.stdout == ""
