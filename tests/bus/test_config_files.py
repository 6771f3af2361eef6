"""A service's --zenoh-config file and its endpoints, checked before anything starts: a config whose
certificate or key files are not where it says, and a protocol this Zenoh cannot use, are usage
errors naming them (Zenoh itself says only that a TLS link timed out, or `Unicast not supported`)."""

import argparse
import json
import subprocess
import sys

import pytest
import zenoh

from services import certs
from services.bus.config import PROTOCOLS, TLS_FILES, make_config, zenoh_config_file


def refused(tmp_path, *argv: str) -> str:
    """A `spikinglab` process with `argv` ended as a usage error (exit 2): its one line on stderr."""
    done = subprocess.run(
        [sys.executable, "-m", "spikinglab", *argv], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr, done.stderr
    return done.stderr


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    folder = tmp_path_factory.mktemp("certs")
    assert certs.main([str(folder)]) == 0
    return folder


@pytest.mark.parametrize("role", ["brain", "router"])
def test_a_config_moved_without_its_certificates_names_the_file_it_lacks(made, tmp_path, role):
    moved = tmp_path / "moved.json5"
    moved.write_text((made / f"{role}.json5").read_text().replace(str(made), "/elsewhere/certs"))
    side = "--listen" if role == "router" else "--connect"
    err = refused(tmp_path, role, "--zenoh-config", str(moved), side, "tls/127.0.0.1:17472")
    assert f"argument --zenoh-config: {moved}: transport.link.tls.root_ca_certificate /elsewhere/certs/ca.pem" in err


@pytest.mark.parametrize("field", TLS_FILES)
def test_every_tls_file_field_is_checked(made, tmp_path, field):
    mine = {"root_ca_certificate": "ca.pem"}
    tls = {name: str(made / mine.get(name, "brain.key" if name.endswith("key") else "brain.pem")) for name in TLS_FILES}
    path = tmp_path / "config.json5"
    path.write_text(json.dumps({"mode": "client", "transport": {"link": {"tls": tls}}}))
    assert zenoh_config_file(str(path))["settings"]["transport"]["link"]["tls"] == tls
    for missing, why in [(tmp_path / "gone.pem", "No such file or directory"), (tmp_path, "Is a directory")]:
        path.write_text(json.dumps({"transport": {"link": {"tls": tls | {field: str(missing)}}}}))
        with pytest.raises(argparse.ArgumentTypeError, match=f"transport.link.tls.{field} {missing}: {why}"):
            zenoh_config_file(str(path))


def test_an_endpoint_of_a_protocol_zenoh_cannot_use_is_a_usage_error(tmp_path):
    for option, address in [("--listen", "vsock/xyz"), ("--connect", "serial//dev/ttyUSB0")]:
        err = refused(tmp_path, "world", option, address)
        assert f"argument {option}: {address!r} is not an endpoint" in err


def test_zenoh_can_listen_on_every_protocol_an_endpoint_may_name(tmp_path):
    """Every protocol the check lets through reaches Zenoh's own link for it (TLS and QUIC then want
    a certificate): none is one this Zenoh was built without."""
    addresses = {"unixsock-stream": str(tmp_path / "bus.sock")}
    for protocol in PROTOCOLS:
        listen = f"{protocol}/{addresses.get(protocol, '127.0.0.1:0')}"
        try:
            zenoh.open(make_config(listen=[listen])).close()
        except zenoh.ZError as e:
            assert "not supported" not in str(e) and protocol in ("tls", "quic"), (listen, str(e))
