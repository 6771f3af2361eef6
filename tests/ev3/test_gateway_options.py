"""The gateway's options as a user meets them: an option of the other backend, a --host that is no
MAC address, and a link this machine cannot make are each one line and an exit before the bus,
never ignored nor retried for good."""

import socket
import subprocess
import sys

import pytest

from services.ev3_gateway.service import parser

from ..processes import ROOT


def gateway(*args: str) -> subprocess.CompletedProcess:
    """`spikinglab gateway` with `args`, to its end (a gateway that retries for good times out)."""
    return subprocess.run(
        [sys.executable, "-m", "spikinglab", "gateway", *args], cwd=ROOT, capture_output=True, text=True, timeout=60
    )


def ended_saying(done: subprocess.CompletedProcess, code: int, says: str) -> None:
    assert (done.returncode, done.stderr.count("\n")) == (code, 1), done.stderr
    assert says in done.stderr and "Traceback" not in done.stderr, done.stderr


@pytest.mark.parametrize(
    "args, says",
    [
        (["--backend", "ev3", "--sim-map", "/nonexistent"], "argument --sim-map: only with --backend sim"),
        (["--sim-seed", "3"], "argument --sim-seed: only with --backend sim"),
        (["--link-ms", "0"], "argument --link-ms: only with --backend sim"),
        (["--backend", "sim", "--protocol", "USB"], "argument --protocol: not with --backend sim"),
        (["--backend", "sim", "--host", "00:11:22:33:44:55"], "argument --host: not with --backend sim"),
        (["--backend", "sim", "--speed", "40"], "argument --speed: not with --backend sim"),
    ],
)
def test_an_option_of_the_other_backend_is_refused(args, says):
    ended_saying(gateway(*args), 2, says)


@pytest.mark.parametrize("host", ["zz", "00:16:53:42:2B", "0016.5342.2B99", "00:16:53:42:2B:9Z"])
def test_a_host_that_is_no_mac_address_is_refused(host):
    ended_saying(
        gateway("--protocol", "Bluetooth", "--host", host),
        2,
        f"argument --host: expected the brick's MAC address, e.g. 00:16:53:42:2B:99; got {host!r}",
    )


def test_each_backend_takes_its_own_options_and_the_others_defaults():
    ev3 = parser().parse_args(["--protocol", "Bluetooth", "--host", "00:16:53:42:2b:99", "--speed", "40"])
    assert (ev3.protocol, ev3.host, ev3.speed, ev3.touch_port, ev3.motors) == (
        "Bluetooth",
        "00:16:53:42:2B:99",
        40,
        1,
        "BC",
    )
    assert (ev3.sim_seed, ev3.sim_map, ev3.sim_patch_cm, ev3.sim_object_cm, ev3.link_ms) == (0, None, 30.0, 15.0, 5.0)
    sim = parser().parse_args(["--backend", "sim", "--sim-seed", "3", "--link-ms", "0"])
    assert (sim.sim_seed, sim.link_ms, sim.sim_patch_cm) == (3, 0.0, 30.0)
    assert (sim.protocol, sim.host, sim.colour_port, sim.ultrasonic_port, sim.spin_speed) == ("WiFi", None, 3, 4, 30)


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
