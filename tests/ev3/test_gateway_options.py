"""The gateway's options as a user meets them: a --host that is no MAC address and a link this
machine cannot make are each one line and an exit before the bus, never retried for good."""

import socket
import subprocess
import sys

import pytest

from ..processes import ROOT


def gateway(*args: str) -> subprocess.CompletedProcess:
    """`spikinglab gateway` with `args`, to its end (a gateway that retries for good times out)."""
    return subprocess.run(
        [sys.executable, "-m", "spikinglab", "gateway", *args], cwd=ROOT, capture_output=True, text=True, timeout=60
    )


def ended_saying(done: subprocess.CompletedProcess, code: int, says: str) -> None:
    assert (done.returncode, done.stderr.count("\n")) == (code, 1), done.stderr
    assert says in done.stderr and "Traceback" not in done.stderr, done.stderr


@pytest.mark.parametrize("host", ["zz", "00:16:53:42:2B", "0016.5342.2B99", "00:16:53:42:2B:9Z"])
def test_a_host_that_is_no_mac_address_is_refused(host):
    ended_saying(
        gateway("--protocol", "Bluetooth", "--host", host),
        2,
        f"argument --host: expected the brick's MAC address, e.g. 00:16:53:42:2B:99; got {host!r}",
    )


def no_libusb() -> bool:
    import usb.core

    try:
        usb.core.find(find_all=True)
    except usb.core.NoBackendError:
        return True
    return False


@pytest.mark.skipif(sys.platform == "darwin" or not no_libusb(), reason="libusb is installed here")
def test_usb_without_libusb_says_what_to_install_and_ends():
    ended_saying(gateway("--protocol", "USB"), 1, "--protocol USB needs libusb")


@pytest.mark.skipif(hasattr(socket, "AF_BLUETOOTH"), reason="this Python has Bluetooth sockets")
def test_bluetooth_without_bluetooth_sockets_says_so_and_ends():
    ended_saying(
        gateway("--protocol", "Bluetooth", "--host", "00:16:53:42:2B:99"),
        1,
        "--protocol Bluetooth needs Bluetooth sockets (socket.AF_BLUETOOTH), which this Python was built without",
    )
