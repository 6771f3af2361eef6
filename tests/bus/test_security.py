"""The secured bus of `spikinglab certs`: mutual TLS and the router's access control, with real
processes on loopback. A peer without a certificate cannot connect; a peer with a valid certificate
of another role reads the run but cannot steer it, end it or move the robot."""

import argparse
import contextlib
import json
import re
import stat
import threading
import time

import json5
import numpy as np
import pytest
import zenoh
from cryptography import x509

from services import certs
from services.brain.checkpoint import load_weights
from services.brain.circuit import load_circuit
from services.bus import keys
from services.bus.config import make_config, zenoh_config_file
from services.bus.schemas import Array, Control, Motor, Sensors, WorldMap, decode, encode
from services.ev3_gateway.fake_brick import FakeBrick
from services.loop import brain_for, closed_loop
from services.world.world import World

from ..processes import bound_port, finish, logged, start, wait_for


@contextlib.contextmanager
def router_on(config, log):
    """A router with the Zenoh config file `config`, for as long as the block lasts: its endpoint."""
    router = start(  # TLS needs TCP: the router binds a free port itself (port 0), read back from the system
        "router", "--listen", "tls/127.0.0.1:0", "--zenoh-config", config, log=log
    )
    try:
        yield f"tls/127.0.0.1:{bound_port(router)}"
    finally:
        router.kill()
        router.wait()


@pytest.fixture
def secure_bus(tmp_path):
    """A CA and certificates in tmp_path/certs, and a router with their rules: (its endpoint, the folder)."""
    folder = tmp_path / "certs"
    assert certs.main([str(folder)]) == 0
    with router_on(folder / "router.json5", tmp_path / "router.log") as endpoint:
        yield endpoint, folder


# a client refused gives up after 3 s, not a service's 10: a TLS handshake on loopback takes ms
GIVE_UP_SOON = {"connect": {"timeout_ms": {"client": 3000}}}


def session_as(role: str, folder, endpoint: str, settings: dict | None = None) -> zenoh.Session:
    """A session with `role`'s certificate, and `settings` over its config file's."""
    config = zenoh_config_file(str(folder / f"{role}.json5"))
    config["settings"] = config["settings"] | (settings or {})
    return zenoh.open(make_config(connect=[endpoint], config_file=config))


def secured(role: str, folder, endpoint: str) -> tuple:
    """A service's options to join the secured bus as `role`: the router's endpoint, the role's config."""
    return ("--connect", endpoint, "--zenoh-config", folder / f"{role}.json5")


def test_certs_makes_a_ca_and_a_certificate_and_config_per_role(tmp_path, caplog, capsys):
    folder = tmp_path / "certs"
    assert certs.main([str(folder), "--host", "192.168.1.10", "--host", "lab-pc.local"]) == 0
    assert "wrote a CA, certificates and Zenoh configs for" in capsys.readouterr().out
    ca = x509.load_pem_x509_certificate((folder / "ca.pem").read_bytes())
    for role in certs.PUTS:
        cert = x509.load_pem_x509_certificate((folder / f"{role}.pem").read_bytes())
        cert.verify_directly_issued_by(ca)
        assert cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)[0].value == role
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert set(map(str, names.get_values_for_type(x509.IPAddress))) == {"127.0.0.1", "192.168.1.10"}
        assert set(names.get_values_for_type(x509.DNSName)) == {"localhost", "lab-pc.local"}
        assert stat.S_IMODE((folder / f"{role}.key").stat().st_mode) == 0o600
        config = json5.loads((folder / f"{role}.json5").read_text())
        assert config["mode"] == ("router" if role == "router" else "client")
        assert config["scouting"]["multicast"]["enabled"] is False
    # made again: the same CA (certificates already handed out stay valid), new certificates
    assert certs.main([str(folder)]) == 0
    assert x509.load_pem_x509_certificate((folder / "ca.pem").read_bytes()) == ca
    assert "named 192.168.1.10, lab-pc.local too, which the new ones do not (give --host again" in caplog.text
    assert "wrote certificates of the CA there and Zenoh configs for" in capsys.readouterr().out
    assert certs.main([str(folder), "--host", "192.168.1.10"]) == 0
    caplog.clear()
    assert certs.main([str(folder), "--new-ca"]) == 0  # a new CA: the old router certificate's names do not count
    assert "which the new ones do not" not in caplog.text


def files_in(folder) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in folder.iterdir()}


def certs_refused(argv: list[str], capsys) -> str:
    """`spikinglab certs` with `argv` ended as a usage error (exit 2): its one line on stderr."""
    assert certs.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("kept, lost", [("ca.pem", "ca.key"), ("ca.key", "ca.pem")])
def test_certs_refuses_a_folder_with_half_a_ca_and_changes_nothing(tmp_path, capsys, kept, lost):
    """A new CA there would cut off every machine that trusts the old one: only --new-ca makes it."""
    folder = tmp_path / "certs"
    assert certs.main([str(folder)]) == 0
    (folder / lost).unlink()
    before = files_in(folder)
    err = certs_refused([str(folder)], capsys)
    assert f"{folder / kept} is here but {lost} is not" in err
    assert files_in(folder) == before
    assert certs.main([str(folder), "--new-ca"]) == 0
    assert (folder / lost).exists() and (folder / kept).read_bytes() != before[kept]


@pytest.mark.parametrize(
    "name, content, says",
    [
        ("ca.key", b"", "ca.key is empty, not a PEM private key"),
        ("ca.key", b"garbage\n", "ca.key is not a PEM private key without a password: "),
        ("ca.pem", b"garbage\n", "ca.pem is not a PEM certificate: "),
        ("ca.key", None, "ca.key is not the key of "),  # another CA's key
    ],
    ids=["empty key", "garbage key", "garbage certificate", "another CA's key"],
)
def test_certs_names_the_ca_file_it_cannot_use_and_changes_nothing(tmp_path, capsys, name, content, says):
    folder, other = tmp_path / "certs", tmp_path / "other"
    assert certs.main([str(folder)]) == 0 and certs.main([str(other)]) == 0
    (folder / name).write_bytes((other / name).read_bytes() if content is None else content)
    before = files_in(folder)
    err = certs_refused([str(folder)], capsys)
    assert f"{folder / name}" in err and says in err
    assert files_in(folder) == before


def test_certs_refuses_days_past_its_bound_before_making_anything(tmp_path, capsys):
    folder = tmp_path / "certs"
    with pytest.raises(SystemExit) as ended:
        certs.main([str(folder), "--days", str(certs.MOST_DAYS + 1)])
    assert ended.value.code == 2
    assert f"argument --days: must be at most {certs.MOST_DAYS:,}" in capsys.readouterr().err
    assert not folder.exists()


def test_a_config_whose_certificate_is_of_another_ca_or_expired_is_refused_naming_it(tmp_path):
    """Before the session: Zenoh would say only that the TLS link timed out."""
    ours, other = tmp_path / "ours", tmp_path / "other"
    assert certs.main([str(ours)]) == 0 and certs.main([str(other)]) == 0
    config = json5.loads((ours / "brain.json5").read_text())
    config["transport"]["link"]["tls"]["connect_certificate"] = str(other / "brain.pem")
    (tmp_path / "mixed.json5").write_text(json.dumps(config))
    with pytest.raises(argparse.ArgumentTypeError, match=r"certificate .*other/brain.pem: not signed by the CA"):
        zenoh_config_file(str(tmp_path / "mixed.json5"))
    assert zenoh_config_file(str(ours / "brain.json5"))  # the control: its own certificate fits
    key, ca = certs.load_ca(ours)
    certs.make_certificate(ours, "brain", ["127.0.0.1"], key, ca, days=0)  # expired as it is made
    with pytest.raises(argparse.ArgumentTypeError, match=r"brain.pem: valid from .* UTC, not now"):
        zenoh_config_file(str(ours / "brain.json5"))


def test_certificates_of_the_longest_days_open_a_session(tmp_path):
    """The bound's certificates are ones Zenoh's TLS takes."""
    folder = tmp_path / "certs"
    assert certs.main([str(folder), "--days", str(certs.MOST_DAYS)]) == 0
    with router_on(folder / "router.json5", tmp_path / "router.log") as endpoint:
        session_as("viewer", folder, endpoint).close()


def test_a_peer_without_a_valid_certificate_cannot_connect(secure_bus, tmp_path):
    endpoint, folder = secure_bus
    with session_as("viewer", folder, endpoint) as viewer:  # the control: a certificate of the CA connects
        assert list(viewer.info.routers_zid())
    no_certificate = {"mode": "client", "transport": {"link": {"tls": {"root_ca_certificate": str(folder / "ca.pem")}}}}
    no_certificate |= GIVE_UP_SOON
    assert certs.main([str(tmp_path / "other"), "--new-ca"]) == 0  # the right roles, from another CA
    with pytest.raises(zenoh.ZError):
        zenoh.open(make_config(connect=[endpoint], config_file={"file": "-", "settings": no_certificate}))
    with pytest.raises(zenoh.ZError):
        session_as("brain", tmp_path / "other", endpoint, GIVE_UP_SOON)
    with pytest.raises(zenoh.ZError):  # nor in the clear
        zenoh.open(
            make_config(
                connect=[endpoint.replace("tls/", "tcp/")],
                config_file={"file": "-", "settings": {"mode": "client"} | GIVE_UP_SOON},
            )
        )


def test_a_service_at_a_tls_endpoint_without_certificates_is_told_it_needs_them(secure_bus, tmp_path):
    """The TLS router is there, but a service given its tls/ endpoint and no --zenoh-config cannot
    reach it: its "nothing answers" names the certificates missing, not only the other side."""
    endpoint, _ = secure_bus
    log = tmp_path / "brain.log"
    brain = start("brain", "--connect", endpoint, "--group", tmp_path.name, log=log)
    try:
        wait_for(lambda: "nothing answers" in log.read_text(), 60, "the brain to say that nothing answers")
        logged(
            log.read_text(),
            re.escape(
                f"nothing answers at {endpoint} after 10 s (is the other side running, and is the endpoint right?)"
            )
            + re.escape("; still trying; a tls/ endpoint needs --zenoh-config with this machine's certificates"),
        )
    finally:
        brain.terminate()
        brain.wait(10)


def test_a_client_given_the_tls_routers_port_as_tcp_is_told_to_use_tls(secure_bus, tmp_path):
    """A client with its certificates but a tcp/ endpoint at the TLS router: Zenoh says only
    "Timeout!"; the service adds where a secured router is reached."""
    endpoint, folder = secure_bus
    log = tmp_path / "brain.log"
    brain = start("brain", *secured("brain", folder, endpoint.replace("tls/", "tcp/")), log=log)
    assert finish(brain, 120, log) == 1
    logged(
        log.read_text(),
        re.escape(f"cannot open the bus session (connect ['{endpoint.replace('tls/', 'tcp/')}']")
        + r".*Unable to connect.*"
        + re.escape("; a router secured with TLS is reached at its tls/ endpoint (docs/security.md)"),
    )


def key_or_error(reply: zenoh.Reply) -> str:
    """A reply's key, or the text of an error reply."""
    if reply.ok is not None:
        return str(reply.ok.key_expr)
    assert reply.err is not None  # a reply is a sample or an error
    return f"error: {reply.err.payload.to_bytes()!r}"


def others_admin_space(role: str, folder, endpoint: str) -> list[str]:
    """What `role`'s get on the admin space receives from any session but its own: the keys of the
    replies, and the text of any error reply. Its own session always answers it (about its own
    link to the router, under @/<its id>/session/), which shows the get was made."""
    with session_as(role, folder, endpoint) as session:
        own = f"@/{session.zid()}/session/"
        replies = list(session.get(certs.ADMIN_SPACE, timeout=2))
        keys_seen = [key_or_error(r) for r in replies]
    assert any(key.startswith(own) for key in keys_seen), keys_seen
    return [key for key in keys_seen if not key.startswith(own)]


def router_config_with(folder, name: str, admin_space: bool, default: str, deny_rule: bool):
    """router.json5 with the admin space on or off, the default permission, with or without the
    rule that denies the admin space: a copy named `name`."""
    config = json5.loads((folder / "router.json5").read_text())
    config["adminspace"] = {"enabled": admin_space}
    control = config["access_control"]
    control["default_permission"] = default
    if not deny_rule:
        control["rules"] = [r for r in control["rules"] if r["id"] != certs.NO_ADMIN_SPACE["id"]]
        for policy in control["policies"]:
            policy["rules"].remove(certs.NO_ADMIN_SPACE["id"])
    path = folder / name
    path.write_text(json.dumps(config))
    return path


def test_no_role_reads_the_routers_admin_space(secure_bus, tmp_path):
    endpoint, folder = secure_bus
    for role in ("viewer", "recorder"):  # the router as `spikinglab certs` writes it
        assert others_admin_space(role, folder, endpoint) == []
    # the admin space switched on and every message allowed by default: the rule alone still denies it
    opened = router_config_with(folder, "opened.json5", admin_space=True, default="allow", deny_rule=True)
    with router_on(opened, tmp_path / "opened.log") as opened_endpoint:
        for role in ("viewer", "recorder"):
            assert others_admin_space(role, folder, opened_endpoint) == []
    # the control: the same without the rule, and the router tells every role about its sessions
    control = router_config_with(folder, "control.json5", admin_space=True, default="allow", deny_rule=False)
    with router_on(control, tmp_path / "control.log") as control_endpoint:
        for role in ("viewer", "recorder"):
            seen = others_admin_space(role, folder, control_endpoint)
            assert any(key.endswith("/router") for key in seen), seen  # @/<router's id>/router: its sessions


class Forger:
    """A session of `role` that reads the sensors (learning the run id and tick) and answers each
    with what only the brain, the world or the gateway may send: motor ROTATE for that run, an end
    of that run at that tick, and the brain's liveliness token."""

    def __init__(self, role: str, folder, endpoint: str):
        self.session = session_as(role, folder, endpoint)
        self.seen = 0
        self.token = self.session.liveliness().declare_token(keys.alive(keys.DEFAULT_GROUP, "brain"))
        self.motor = self.session.declare_publisher(keys.motor(keys.DEFAULT_GROUP))
        self.control = self.session.declare_publisher(keys.control(keys.DEFAULT_GROUP))
        self.sub = self.session.declare_subscriber(keys.sensors(keys.DEFAULT_GROUP), self.answer)

    def answer(self, sample) -> None:
        reading = decode(sample.payload.to_bytes(), Sensors)
        assert isinstance(reading, Sensors)
        self.seen += 1
        agents = reading.values.numpy("values", "<f8", 2).shape[0]
        self.motor.put(
            encode(
                Motor(
                    tick=reading.tick,
                    run=reading.run,
                    names=("rotate", "move"),
                    actions=Array.of(np.ones((agents, 2), np.uint8)),
                )
            ),
            attachment=b"brain@1",
        )
        if reading.tick % 50 == 0:
            self.control.put(encode(Control(tick=reading.tick, run=reading.run, command="end")), attachment=b"world@1")

    def close(self) -> None:
        self.sub.undeclare()
        self.token.undeclare()
        self.session.close()


@pytest.mark.parametrize("role", ["viewer", "recorder"])
def test_another_role_reads_the_run_but_cannot_steer_or_end_it(secure_bus, tmp_path, role):
    endpoint, folder = secure_bus
    ticks, seed = 3000, 4
    world = World(seed=seed)
    brain = brain_for(world, load_circuit("insect"))
    closed_loop(world, brain, ticks)  # the run as it must come out, undisturbed

    forger = Forger(role, folder, endpoint)
    world_args = (*secured("world", folder, endpoint), "--ticks", ticks, "--seed", seed, "--out", tmp_path)
    p_world = start("world", *world_args, log=tmp_path / "world.log")
    brain_args = (*secured("brain", folder, endpoint), "--once", "--save", tmp_path / "weights.npz")
    p_brain = start("brain", *brain_args, log=tmp_path / "brain.log")
    try:
        assert finish(p_world, 120, tmp_path / "world.log") == 0
        assert finish(p_brain, 30, tmp_path / "brain.log") == 0
    finally:
        forger.close()
        p_world.kill()
        p_brain.kill()
    assert forger.seen > ticks // 2  # it was on the bus and read the run (and forged an answer to each reading)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["ticks"] == ticks and metrics["rejected_messages"] == {}  # nothing forged even arrived
    assert metrics["collisions"] == world.metrics.collisions.tolist()
    np.testing.assert_array_equal(load_weights(tmp_path / "weights.npz", brain.circuit), brain.engine.get_weights())


def test_only_the_brain_role_moves_the_robot(secure_bus, tmp_path):
    endpoint, folder = secure_bus
    with FakeBrick() as brick:
        gateway = start(
            "gateway", "--backend", "ev3", *secured("gateway", folder, endpoint), log=tmp_path / "gateway.log"
        )
        try:
            wait_for(lambda: brick.reads > 200, 60, "the gateway to poll the brick")
            viewer = Forger("viewer", folder, endpoint)
            try:
                wait_for(lambda: viewer.seen > 300, 30, "the viewer to read the robot's sensors")
            finally:
                viewer.close()
            assert not brick.commands  # hundreds of forged ROTATEs for the robot's run: not one reached it

            brain = Forger("brain", folder, endpoint)  # the control: the same forgery with the brain's certificate
            try:
                wait_for(lambda: any(c.turn for c in brick.commands), 30, "the brain's certificate to move the robot")
            finally:
                brain.close()
            time.sleep(0.5)
            assert gateway.poll() is None  # the forged ends of run did not end it either
        finally:
            gateway.terminate()
            finish(gateway, 30, tmp_path / "gateway.log")


# what each role's puts and liveliness tokens reach another process through the router (below
# spikinglab/<group>/): written out here, not read from certs.PUTS, so that a rule that is wrong fails
TRIED_KEYS = ("sensors", "sensors/2of3", "motor", "control", "state/world", "state/map", "state/brain", "world/run")
TRIED_TOKENS = (
    "world",
    "world-2of3",
    "world-2of3-done",
    "world-2of3-waiting-1f2e3d",
    "world-x",
    "world-leaving",
    "brain",
    "brain-2of3",
    "brain-2of3-leaving",
    "gateway",
    "gateway-leaving",
    "viewer",
    "recorder",
)
ARRIVES = {
    "world": (
        {"sensors", "sensors/2of3", "control", "state/world", "state/map", "world/run"},
        {"world", "world-2of3", "world-2of3-done", "world-2of3-waiting-1f2e3d", "world-leaving"},
    ),
    "brain": ({"motor", "state/brain"}, {"brain", "brain-2of3", "brain-2of3-leaving"}),
    "gateway": ({"sensors", "control"}, {"gateway", "gateway-leaving"}),
    "viewer": (set(), {"viewer"}),
    "recorder": (set(), {"recorder"}),
}


def arriving(role: str, folder, endpoint: str, listener: zenoh.Session) -> tuple[set[str], set[str]]:
    """The keys and liveliness tokens of TRIED_KEYS and TRIED_TOKENS that reach `listener` when a
    session of `role` puts on each (again and again) and declares each (in a group of its own)."""
    group, puts, tokens = f"as-{role}", set(), set()
    prefix = f"{keys.PREFIX}/{group}/"
    sub = listener.declare_subscriber(f"{prefix}**", lambda s: puts.add(str(s.key_expr).removeprefix(prefix)))
    alive = listener.liveliness().declare_subscriber(
        keys.alive(group, "*"), lambda s: tokens.add(str(s.key_expr).rsplit("/", 1)[-1]), history=True
    )
    expected_keys, expected_tokens = ARRIVES[role]
    with session_as(role, folder, endpoint) as session:
        declared = [session.liveliness().declare_token(keys.alive(group, t)) for t in TRIED_TOKENS]
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not (puts >= expected_keys and tokens >= expected_tokens):
            for key in TRIED_KEYS:
                session.put(prefix + key, b"forged")
            time.sleep(0.05)
        time.sleep(0.5)  # what would arrive besides the expected had the same time and more
        for token in declared:
            token.undeclare()
    sub.undeclare()
    alive.undeclare()
    return puts, tokens


def test_each_role_puts_only_its_own_keys_and_holds_only_its_own_tokens(secure_bus):
    endpoint, folder = secure_bus
    with session_as("recorder", folder, endpoint) as listener:
        for role, (expected_keys, expected_tokens) in ARRIVES.items():
            assert arriving(role, folder, endpoint, listener) == (expected_keys, expected_tokens), role


FORGED_RUN = "0123456789abcdef"


@contextlib.contextmanager
def naming_a_run(role: str, folder, endpoint: str):
    """A session of `role` that puts FORGED_RUN on the world run key every 20 ms while the block
    lasts, as a sharded world's lead names its run: the count of puts (a list of one int)."""
    named = encode(WorldMap(tick=0, run=FORGED_RUN, grid=Array.of(np.zeros((1, 4, 4), np.uint8)), x_min=0, y_min=0))
    assert isinstance(decode(named, WorldMap), WorldMap)  # a shard would take it, were it let through
    session, stop, count = session_as(role, folder, endpoint), threading.Event(), [0]
    publisher = session.declare_publisher(keys.world_run(keys.DEFAULT_GROUP))

    def name() -> None:
        while not stop.wait(0.02):
            publisher.put(named, attachment=b"world@1")
            count[0] += 1

    thread = threading.Thread(target=name, daemon=True)
    thread.start()
    try:
        yield count
    finally:
        stop.set()
        thread.join()
        session.close()


def test_world_and_brain_shards_run_on_the_secured_bus_and_no_other_role_names_their_run(secure_bus, tmp_path):
    endpoint, folder = secure_bus
    ticks, agents = 600, 4
    run = ("--ticks", ticks, "--agents", agents, "--shards", 2, "--out", tmp_path)
    world = (*secured("world", folder, endpoint), *run)
    with naming_a_run("viewer", folder, endpoint) as forged:
        processes = [start("world", *world, "--shard", "2/2", log=tmp_path / "world2.log")]
        try:  # shard 2 listens for the run's name (while the viewer forges one) before the lead names it
            heard = re.compile(r"to name the run|world shard 2/2: run")
            wait_for(lambda: heard.search((tmp_path / "world2.log").read_text()), 60, "shard 2 to listen")
            assert FORGED_RUN not in (tmp_path / "world2.log").read_text()  # it has not taken the forged name
            processes.append(start("world", *world, "--shard", "1/2", log=tmp_path / "world1.log"))
            processes += [
                start(
                    "brain",
                    *secured("brain", folder, endpoint),
                    "--shard",
                    f"{j}/2",
                    "--world-shards",
                    2,
                    "--once",
                    log=tmp_path / f"brain{j}.log",
                )
                for j in (1, 2)
            ]
            logs = ["world2.log", "world1.log", "brain1.log", "brain2.log"]
            for process, log in zip(processes, logs):
                assert finish(process, 120, tmp_path / log) == 0
        finally:
            for process in processes:
                process.kill()
    assert forged[0] > 100
    runs = [logged((tmp_path / f"world{i}.log").read_text(), r"run (\w+): \d+ ticks").group(1) for i in (1, 2)]
    assert runs[0] == runs[1] != FORGED_RUN  # shard 2 followed the lead, not the viewer's forgery
    alone = World(seed=0, agents=agents)
    closed_loop(alone, brain_for(alone, load_circuit("insect")), ticks)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["world_shards"] == 2 and metrics["agents"] == agents and metrics["ticks"] == ticks
    assert not metrics["partial"] and metrics["rejected_messages"] == {}
    assert metrics["collisions"] == alone.metrics.collisions.tolist() and sum(metrics["collisions"]) > 0
