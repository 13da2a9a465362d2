"""Security on zenoh's own terms (ARCHITECTURE principle 7): ``--zenoh-config`` carries TLS
certificates and access-control lists; nothing here is home-made. Certificates are made by
the test with openssl; everything listens on loopback only."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest
import zenoh

from bus import SessionOptions, UsageError, WallClock
from bus.transport import Bus
from hexbench.cli import main
from processes import free_port

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl")


def _certs(d) -> dict[str, str]:
    """A CA and a server certificate for localhost, signed by it."""
    run = lambda *a: subprocess.run(["openssl", *a], cwd=d, check=True, capture_output=True)  # noqa: E731
    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.crt",
        "-days", "2", "-subj", "/CN=hexbench test CA")
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "server.key", "-out", "server.csr",
        "-subj", "/CN=localhost")
    (d / "ext.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    run("x509", "-req", "-in", "server.csr", "-CA", "ca.crt", "-CAkey", "ca.key", "-CAcreateserial",
        "-out", "server.crt", "-days", "2", "-extfile", "ext.cnf")
    server, client = d / "server.json5", d / "client.json5"
    server.write_text('{ transport: { link: { tls: { listen_private_key: "%s", listen_certificate: "%s" } } } }'
                      % (d / "server.key", d / "server.crt"))
    client.write_text('{ transport: { link: { tls: { root_ca_certificate: "%s" } } } }' % (d / "ca.crt"))
    return {"server": str(server), "client": str(client)}


def test_tls_lets_in_who_has_the_ca_and_no_one_else(tmp_path):
    conf = _certs(tmp_path)
    port = 20000 + os.getpid() % 1000
    endpoint = f"tls/localhost:{port}"
    fleet = "tls"
    server = Bus(WallClock(), fleet, options=SessionOptions(listen=[endpoint], config=conf["server"]))
    got: list[bytes] = []
    server.subscribe(f"hexbot/{fleet}/**", lambda k, p: got.append(p))
    client = Bus(WallClock(), fleet, options=SessionOptions(mode="client", connect=[endpoint],
                                                            config=conf["client"]))
    try:
        assert client.wait_remote(f"hexbot/{fleet}/world/sync", timeout_s=10)
        client.put(f"hexbot/{fleet}/world/sync", b"{}")
        server.clock.run(until=lambda: got, timeout_s=10)
        assert got == [b"{}"]
        with pytest.raises(zenoh.ZError, match="Unable to connect"):  # no CA: the handshake fails
            Bus(WallClock(), fleet, options=SessionOptions(mode="client", connect=[endpoint]))
    finally:
        client.close()
        server.close()


def _mtls(d, conf: dict[str, str]) -> dict[str, str]:
    """Mutual TLS: the router asks every participant for a certificate signed by the CA."""
    run = lambda *a: subprocess.run(["openssl", *a], cwd=d, check=True, capture_output=True)  # noqa: E731
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "client.key", "-out", "client.csr",
        "-subj", "/CN=hexbench participant")
    (d / "client.cnf").write_text("extendedKeyUsage=clientAuth\n")
    run("x509", "-req", "-in", "client.csr", "-CA", "ca.crt", "-CAkey", "ca.key", "-CAcreateserial",
        "-out", "client.crt", "-days", "2", "-extfile", "client.cnf")
    server, client = d / "mserver.json5", d / "mclient.json5"
    server.write_text('{ transport: { link: { tls: { listen_private_key: "%s", listen_certificate: "%s", '
                      'root_ca_certificate: "%s", enable_mtls: true } } } }'
                      % (d / "server.key", d / "server.crt", d / "ca.crt"))
    client.write_text('{ transport: { link: { tls: { root_ca_certificate: "%s", enable_mtls: true, '
                      'connect_private_key: "%s", connect_certificate: "%s" } } } }'
                      % (d / "ca.crt", d / "client.key", d / "client.crt"))
    return {"server": str(server), "client": str(client), "ca_only": conf["client"]}


def test_mutual_tls_lets_in_only_participants_with_a_certificate(tmp_path):
    conf = _mtls(tmp_path, _certs(tmp_path))
    port = free_port()
    endpoint = f"tls/localhost:{port}"
    fleet = "mtls"
    server = Bus(WallClock(), fleet, options=SessionOptions(listen=[endpoint], config=conf["server"]))
    got: list[bytes] = []
    server.subscribe(f"hexbot/{fleet}/**", lambda k, p: got.append(p))
    client = Bus(WallClock(), fleet, options=SessionOptions(mode="client", connect=[endpoint],
                                                            config=conf["client"]))
    try:
        assert client.wait_remote(f"hexbot/{fleet}/world/sync", timeout_s=10)
        client.put(f"hexbot/{fleet}/world/sync", b"{}")
        server.clock.run(until=lambda: got, timeout_s=10)
        assert got == [b"{}"]
        # the CA alone (server authentication) is not enough any more
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            Bus(WallClock(), fleet, options=SessionOptions(mode="client", connect=[endpoint],
                                                           config=conf["ca_only"]))
    finally:
        client.close()
        server.close()


def test_an_access_control_list_keeps_a_denied_put_from_the_fleet(tmp_path):
    acl = tmp_path / "acl.json5"
    acl.write_text("""{ access_control: { enabled: true, default_permission: "allow",
        rules: [ { id: "no-inject", messages: ["put"], flows: ["ingress"], permission: "deny",
                   key_exprs: ["hexbot/acl/world/inject"] } ],
        subjects: [ { id: "loopback", interfaces: ["lo"] } ],
        policies: [ { rules: ["no-inject"], subjects: ["loopback"] } ] } }""")
    port = 21000 + os.getpid() % 1000
    results = {}
    for name, config in (("open", None), ("acl", str(acl))):
        fleet = "acl"
        server = Bus(WallClock(), fleet, options=SessionOptions(listen=[f"tcp/127.0.0.1:{port}"],
                                                                config=config))
        got: list[str] = []
        server.subscribe(f"hexbot/{fleet}/**", lambda k, p: got.append(k.rsplit("/", 2)[-1]))
        client = Bus(WallClock(), fleet, options=SessionOptions(mode="client",
                                                                connect=[f"tcp/127.0.0.1:{port}"]))
        try:
            assert client.wait_remote(f"hexbot/{fleet}/world/sync", timeout_s=10)
            client.put(f"hexbot/{fleet}/world/inject", b'{"fault": "m1.S1-:off"}')
            client.put(f"hexbot/{fleet}/world/sync", b"{}")  # after it: once this arrived, so had that
            server.clock.run(until=lambda: "sync" in got, timeout_s=10)
            results[name] = got
        finally:
            client.close()
            server.close()
        port += 1
    assert results["open"] == ["inject", "sync"]  # the check has teeth
    assert results["acl"] == ["sync"]


def test_which_listeners_are_warned_about():
    from bus.session import _private

    assert not _private("tcp/0.0.0.0:7447") and not _private("tcp/10.0.0.5:7447")
    assert _private("tcp/127.0.0.1:7447") and _private("tcp/localhost:7447")
    assert _private("tls/0.0.0.0:7447") and _private("tcp/[::1]:7447")


def test_a_bad_config_file_and_an_open_listener_are_said_plainly(tmp_path, capsys):
    with pytest.raises(UsageError, match="--zenoh-config .*nope.json5: No such file"):
        Bus(WallClock(), "x", options=SessionOptions(config=str(tmp_path / "nope.json5")))
    assert main(["monitor", "--listen", f"tcp/localhost:{22000 + os.getpid() % 1000}",
                 "--seconds", "0.1"]) == 0
    assert "warning" not in capsys.readouterr().err  # loopback: nobody else reaches it
    assert main(["monitor", "--zenoh-config", str(tmp_path / "nope.json5"), "--seconds", "0.1"]) == 2
    assert "hexbench monitor: error: --zenoh-config" in capsys.readouterr().err
