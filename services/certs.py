"""`spikinglab certs DIR`: a certificate authority, a certificate per service, and the Zenoh configs
of a bus where only the right process may publish each key (docs/security.md).

In DIR: ca.pem (and ca.key, kept to make more certificates later), <role>.pem and <role>.key for
each role, <role>.json5 a Zenoh config for that role's process (--zenoh-config), router.json5 the
router's, with mutual TLS and the access-control rules below. Every process connects to the router
as a client over tls/ (never to another directly), and the router lets a process put only its own
keys: the world and the gateway sensors and control, the brain motor, each its own state and its
own liveliness tokens (its shards' too), a sharded world's lead the run id; a viewer (or a
recorder) may subscribe to everything and put nothing. No role may query the router's admin space
(@/...), which is off as well.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import json
import logging
import os
import re
import sys
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from services.bus import keys
from services.options import Parser, folder_path, whole_within

log = logging.getLogger("spikinglab.certs")

# role -> the keys (below spikinglab/<group>/) its process may put
PUTS = {
    "router": (),
    # sensors/*: a sharded brain's slices; world/run: a sharded world's lead names the run to the others
    "world": ("sensors", "sensors/*", "control", "state/world", "state/map", "world/run"),
    "gateway": ("sensors", "control"),
    "brain": ("motor", "state/brain"),
    "recorder": (),
    "viewer": (),
}
# role -> the liveliness tokens (below spikinglab/<group>/alive/) its process may hold; a role not
# named holds the one of its name. $* is any text within a chunk: the shards' tokens, "world-2of3"
# (and "world-2of3-done" once it has run its ticks, "world-2of3-waiting-<session id>" until it has
# joined), "brain-2of3"; and each, as it leaves of its own accord, that name + "-leaving"
TOKENS = {
    "world": (
        "world",
        "world-$*of$*",
        "world-$*of$*-done",
        "world-$*of$*-waiting-$*",
        "world-leaving",
        "world-$*of$*-leaving",
    ),
    "brain": ("brain", "brain-$*of$*", "brain-leaving", "brain-$*of$*-leaving"),
}
EVERY_GROUP = f"{keys.PREFIX}/*"
READ = {  # what every role may do: subscribe to any key of any group and be sent what is put there
    "ingress": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
    "egress": ["put", "delete", "liveliness_token", "reply", "declare_subscriber"],
}
ADMIN_SPACE = "@/**"  # a router's own information (its sessions, their addresses, every key declared)
EVERY_MESSAGE = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]
NO_ADMIN_SPACE = {  # for every role: a deny rule holds even where another rule or the default allows
    "id": "no admin space",
    "permission": "deny",
    "flows": ["ingress", "egress"],
    "messages": EVERY_MESSAGE,
    "key_exprs": [ADMIN_SPACE],
}


def _name(common_name: str) -> x509.Name:
    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "spikinglab"),
            x509.NameAttribute(NameOID.COMMON_NAME, common_name),
        ]
    )


def _write_key(path: Path, key) -> None:
    path.write_bytes(
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    path.chmod(0o600)


def _alternative_names(hosts: list[str]) -> x509.SubjectAlternativeName:
    names = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return x509.SubjectAlternativeName(names)


def make_ca(folder: Path, days: int):
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(_name("spikinglab CA"))
        .issuer_name(_name("spikinglab CA"))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                key_cert_sign=True,
                crl_sign=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    _write_key(folder / "ca.key", key)
    (folder / "ca.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return key, cert


class UnreadableCA(ValueError):
    """The CA in the folder cannot be used; the text names the file and why."""


def _pem(path: Path, load, what: str):
    """`load` of the PEM file at `path`, or UnreadableCA naming it."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise UnreadableCA(f"cannot read {path}: {e.strerror}") from None
    if not data.strip():
        raise UnreadableCA(f"{path} is empty, not {what}") from None
    try:
        return load(data)
    except (ValueError, TypeError) as e:  # TypeError: a key with a password
        reason = re.sub(r" See https://\S+ for more details\.", "", str(e))
        raise UnreadableCA(f"{path} is not {what}: {reason}") from None


def load_ca(folder: Path):
    key = _pem(
        folder / "ca.key",
        lambda data: serialization.load_pem_private_key(data, None),
        "a PEM private key without a password",
    )
    cert = _pem(folder / "ca.pem", x509.load_pem_x509_certificate, "a PEM certificate")
    if key.public_key() != cert.public_key():
        raise UnreadableCA(f"{folder / 'ca.key'} is not the key of {folder / 'ca.pem'}")
    return key, cert


def make_certificate(folder: Path, role: str, hosts: list[str], ca_key, ca_cert, days: int) -> None:
    """<role>.pem and <role>.key: common name = the role (what the router's rules match), valid as a
    server and as a client for `hosts` (the router's must name the address the others dial)."""
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(_name(role))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_alternative_names(hosts), critical=False)
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    _write_key(folder / f"{role}.key", key)
    (folder / f"{role}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def access_control() -> dict:
    """The router's rules: deny by default; everyone reads; each role puts its own keys only; no
    role reaches the admin space."""
    rules = [NO_ADMIN_SPACE] + [
        {
            "id": f"read {flow}",
            "permission": "allow",
            "flows": [flow],
            "messages": messages,
            "key_exprs": [f"{EVERY_GROUP}/**"],
        }
        for flow, messages in READ.items()
    ]
    subjects, policies = [], []
    for role, puts in PUTS.items():
        subjects.append({"id": role, "cert_common_names": [role]})
        own = [f"{EVERY_GROUP}/{key}" for key in puts]
        role_rules = [NO_ADMIN_SPACE["id"], "read ingress", "read egress"]
        rules.append(
            {
                "id": f"{role} alive",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["liveliness_token"],
                "key_exprs": [
                    f"{EVERY_GROUP}/alive/{token}" for token in TOKENS.get(role, (role, role + keys.LEAVING))
                ],
            }
        )
        role_rules.append(f"{role} alive")
        if own:
            rules.append(
                {
                    "id": f"{role} puts",
                    "permission": "allow",
                    "flows": ["ingress"],
                    "messages": ["put"],
                    "key_exprs": own,
                }
            )
            role_rules.append(f"{role} puts")
        policies.append({"id": role, "rules": role_rules, "subjects": [role]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def zenoh_config(folder: Path, role: str) -> dict:
    """`role`'s Zenoh config: the router listens, every other role connects to it as a client,
    each with its own certificate over mutual TLS; the router holds the access-control rules."""
    side = "listen" if role == "router" else "connect"
    config = {
        "mode": "router" if role == "router" else "client",
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "link": {
                "tls": {
                    "root_ca_certificate": str(folder / "ca.pem"),
                    f"{side}_certificate": str(folder / f"{role}.pem"),
                    f"{side}_private_key": str(folder / f"{role}.key"),
                    "enable_mtls": True,
                }
            }
        },
    }
    if role == "router":
        config["adminspace"] = {"enabled": False}  # and the rules deny it to every role, should it be turned on
        config["access_control"] = access_control()
    return config


def write_configs(folder: Path) -> None:
    header = "// written by `spikinglab certs`; docs/security.md says what it allows\n"
    for role in PUTS:
        (folder / f"{role}.json5").write_text(header + json.dumps(zenoh_config(folder, role), indent=2) + "\n")


def host_name(text: str) -> str:
    """--host: an IP address, or a DNS name (letters, digits and hyphens in dot-separated labels)."""
    try:
        return str(ipaddress.ip_address(text))
    except ValueError:
        pass
    labels = text.rstrip(".").split(".")
    if len(text) > 253 or not all(re.fullmatch(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?", x) for x in labels):
        raise argparse.ArgumentTypeError(f"expected an IP address or a host name such as lab-pc.local, got {text!r}")
    return text


MOST_DAYS = 36_500  # 100 years; X.509 dates end with the year 9999


def parser() -> Parser:
    p = Parser(prog="spikinglab certs", description=(__doc__ or "").partition("\n")[0])
    p.add_argument("folder", type=folder_path, metavar="DIR", help="where to write them (made if missing)")
    p.add_argument(
        "--host",
        action="append",
        type=host_name,
        default=[],
        metavar="NAME",
        help="a name or address the router is reached at, besides localhost and 127.0.0.1 "
        "(repeatable; e.g. --host 192.168.1.10 --host lab-pc.local)",
    )
    p.add_argument(
        "--days",
        type=whole_within(1, MOST_DAYS, " (100 years)"),
        default=365,
        help=f"how long the certificates are valid, 1 to {MOST_DAYS:,} (default 365)",
    )
    p.add_argument(
        "--new-ca",
        action="store_true",
        help="make a new CA even if DIR has one (every machine then needs the new files)",
    )
    return p


def hosts_named(certificate: Path) -> list[str]:
    """The names and addresses a certificate was made for ([] where there is none to read)."""
    try:
        names = x509.load_pem_x509_certificate(certificate.read_bytes()).extensions.get_extension_for_class(
            x509.SubjectAlternativeName
        )
    except (OSError, ValueError, x509.ExtensionNotFound):
        return []
    return [str(name.value) for name in names.value]


def existing_ca(folder: Path):
    """The CA in `folder` to sign with, (key, certificate), or None where it has neither ca.pem nor
    ca.key; UnreadableCA where it has one without the other (a new CA there would cut off every
    machine that trusts the old one) or one that cannot be used."""
    here = [name for name in ("ca.pem", "ca.key") if (folder / name).exists()]
    if not here:
        return None
    if len(here) == 1:
        missing = "ca.key" if here == ["ca.pem"] else "ca.pem"
        raise UnreadableCA(
            f"{folder / here[0]} is here but {missing} is not: bring {missing} back, or choose another folder"
        )
    return load_ca(folder)


def main(argv=None) -> int:
    logging.basicConfig(level=logging.INFO, format="certs: %(message)s", stream=sys.stderr)
    args = parser().parse_args(argv)
    folder = args.folder.resolve()
    if folder.exists() and not folder.is_dir():
        print(f"spikinglab certs: {folder} is a file, not a folder for the certificates", file=sys.stderr)
        return 2
    try:
        ca = None if args.new_ca else existing_ca(folder)
    except UnreadableCA as e:
        print(
            f"spikinglab certs: {e} (--new-ca makes a new CA: every machine then needs the new files)", file=sys.stderr
        )
        return 2
    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.chmod(folder, 0o700)
        if ca is None:
            ca_key, ca_cert = make_ca(folder, args.days)
        else:
            ca_key, ca_cert = ca
            log.info("using the CA in %s (--new-ca makes a new one)", folder)
        hosts = ["localhost", "127.0.0.1", *args.host]
        named_before = [] if ca is None else hosts_named(folder / "router.pem")  # a new CA starts afresh
        if dropped := [host for host in named_before if host not in hosts]:
            log.warning(
                "the router's certificate here named %s too, which the new ones do not (give --host again to keep it)",
                ", ".join(dropped),
            )
        for role in PUTS:
            make_certificate(folder, role, hosts, ca_key, ca_cert, args.days)
        write_configs(folder)
    except (OSError, ValueError) as e:
        print(f"spikinglab certs: cannot write the certificates in {folder}: {e}", file=sys.stderr)
        return 1
    made = "a CA, certificates" if ca is None else "certificates of the CA there"
    print(f"wrote {made} and Zenoh configs for {', '.join(PUTS)} in {folder}")
    print(
        "copy ca.pem and a role's .pem, .key and .json5 to the same path on the machine that runs it; keep ca.key safe"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
