"""A stereo head that is not there: the driver says why in words that name no option, and each command that opens
the head adds its own way to the virtual one. The driver told every user "or try --mock for the virtual head", but
``p3at run`` has no --mock (its virtual head is ``--robot mock --camera mock``), and it said so only after connecting
to the robot.

pyusb's lookup is replaced so that the tests do not depend on this machine's libusb or USB devices: without a backend
(no libusb) and with a backend that finds no head."""
from __future__ import annotations

import pytest
import usb.core

from drivers.errors import DeviceNotFoundError
from drivers.videre.transport import UsbTransport
from runtime.cli import main
from runtime.fleet.processes import free_port


def _no_backend(*args, **kwargs):
    raise usb.core.NoBackendError("No backend available")


def _no_device(*args, **kwargs):
    return iter(())


LOOKUPS = {"no libusb": (_no_backend, "no USB backend to look for stereo head 1209:0001"),
           "no head": (_no_device, "no stereo head found at USB 1209:0001")}


@pytest.fixture(params=sorted(LOOKUPS))
def lookup(request, monkeypatch):
    find, message = LOOKUPS[request.param]
    monkeypatch.setattr(usb.core, "find", find)
    return message


def test_the_drivers_message_names_no_option(lookup):
    with pytest.raises(DeviceNotFoundError) as caught:
        UsbTransport.open()
    assert str(caught.value).startswith(lookup)
    assert "--" not in str(caught.value) and "mock" not in str(caught.value)


@pytest.mark.parametrize("action", ["info", "grab"])
def test_p3at_camera_adds_its_mock_option(action, lookup, tmp_path, capsys):
    extra = ["--out", str(tmp_path / "pair")] if action == "grab" else []
    assert main(["camera", action, *extra]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"p3at camera {action}: {lookup}"), err
    assert err[0].endswith("; without the head, --mock uses the virtual one")


def test_p3at_run_adds_its_virtual_head_before_connecting_to_the_robot(lookup, tmp_path, capsys):
    url = f"socket://127.0.0.1:{free_port()}"   # nobody listens: the head is looked for before the robot
    code = main(["run", "--robot", url, "--quiet", "--rerun", "none", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1, (code, err)
    assert err[0].startswith(f"p3at run: {lookup}"), err
    assert err[0].endswith("; without the head, the virtual robot with its virtual head runs as "
                           "p3at run --robot mock --camera mock")
    assert "--mock" not in err[0]
    assert not (tmp_path / "out").exists()
