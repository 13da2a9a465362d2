"""Security on zenoh's own terms (ARCHITECTURE principle 7): ``--zenoh-config`` carries TLS
certificates and access-control lists; nothing here is home-made. Certificates are made by
the test with openssl; everything listens on loopback only."""

from __future__ import annotations

import subprocess

import pytest

from bus import SessionOptions, UsageError, WallClock
from bus.session import ConnectError
from bus.transport import Bus
from hexbench.cli import main
from processes import free_port
from toolchain import needs_tools

pytestmark = needs_tools("openssl")


def _openssl(d, *args: str) -> None:
    subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)


def _signed(d, name: str, subject: str, extension: str) -> None:
    """``name``.key and ``name``.crt for ``subject``, signed by the CA of ``d``."""
    _openssl(d, "req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}.key", "-out", f"{name}.csr",
             "-subj", subject)
    (d / f"{name}.cnf").write_text(extension + "\n")
    _openssl(d, "x509", "-req", "-in", f"{name}.csr", "-CA", "ca.crt", "-CAkey", "ca.key",
             "-CAcreateserial", "-out", f"{name}.crt", "-days", "2", "-extfile", f"{name}.cnf")


def _certs(d) -> dict[str, str]:
    """A CA and a server certificate for localhost, signed by it."""
    _openssl(d, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.crt",
             "-days", "2", "-subj", "/CN=hexbench test CA")
    _signed(d, "server", "/CN=localhost", "subjectAltName=DNS:localhost,IP:127.0.0.1")
    server, client = d / "server.json5", d / "client.json5"
    server.write_text('{ transport: { link: { tls: { listen_private_key: "%s", listen_certificate: "%s" } } } }'
                      % (d / "server.key", d / "server.crt"))
    client.write_text('{ transport: { link: { tls: { root_ca_certificate: "%s" } } } }' % (d / "ca.crt"))
    return {"server": str(server), "client": str(client)}


def _admits_and_refuses(fleet: str, server_conf: str, member_conf: str,
                        outsider_conf: str | None) -> None:
    """A participant with ``member_conf`` joins a TLS listener and its put arrives; one with
    ``outsider_conf`` (None: no TLS configuration at all) cannot connect."""
    endpoint = f"tls/localhost:{free_port()}"
    server = Bus(WallClock(), fleet, options=SessionOptions(listen=[endpoint], config=server_conf))
    got: list[bytes] = []
    server.subscribe(f"hexbot/{fleet}/**", lambda k, p: got.append(p))
    client = Bus(WallClock(), fleet, options=SessionOptions(mode="client", connect=[endpoint],
                                                            config=member_conf))
    try:
        assert client.wait_remote(f"hexbot/{fleet}/world/sync", timeout_s=10)
        client.put(f"hexbot/{fleet}/world/sync", b"{}")
        server.clock.run(until=lambda: got, timeout_s=10)
        assert got == [b"{}"]
        with pytest.raises(ConnectError, match=f"cannot connect to {endpoint}: TLS handshake refused"):
            Bus(WallClock(), fleet, options=SessionOptions(mode="client", connect=[endpoint],
                                                           config=outsider_conf))
    finally:
        client.close()
        server.close()


def test_tls_lets_in_who_has_the_ca_and_no_one_else(tmp_path):
    conf = _certs(tmp_path)
    _admits_and_refuses("tls", conf["server"], conf["client"], None)  # no CA


def _mtls(d, conf: dict[str, str]) -> dict[str, str]:
    """Mutual TLS: the router asks every participant for a certificate signed by the CA."""
    _signed(d, "client", "/CN=hexbench participant", "extendedKeyUsage=clientAuth")
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
    # the CA alone (server authentication) is not enough any more
    _admits_and_refuses("mtls", conf["server"], conf["client"], conf["ca_only"])


def test_an_access_control_list_keeps_a_denied_put_from_the_fleet(tmp_path):
    acl = tmp_path / "acl.json5"
    acl.write_text("""{ access_control: { enabled: true, default_permission: "allow",
        rules: [ { id: "no-inject", messages: ["put"], flows: ["ingress"], permission: "deny",
                   key_exprs: ["hexbot/acl/world/inject"] } ],
        subjects: [ { id: "loopback", interfaces: ["lo"] } ],
        policies: [ { rules: ["no-inject"], subjects: ["loopback"] } ] } }""")
    results = {}
    for name, config in (("open", None), ("acl", str(acl))):
        fleet, port = "acl", free_port()
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
    assert main(["monitor", "--listen", f"tcp/localhost:{free_port()}",
                 "--seconds", "0.1"]) == 0
    assert "warning" not in capsys.readouterr().err  # loopback: nobody else reaches it
    assert main(["monitor", "--zenoh-config", str(tmp_path / "nope.json5"), "--seconds", "0.1"]) == 2
    assert "hexbench monitor: error: --zenoh-config" in capsys.readouterr().err


def test_a_connection_that_fails_is_named_with_its_endpoint_and_cause(tmp_path, capsys):
    """Without the CA a participant is told the TLS handshake was refused, not that no fleet
    listens; at a port nobody holds, that nothing listens there. Either way at once, and
    non-zero: ``send`` (a peer) exits 3, a client fails (1) in one line."""
    import time

    conf = _certs(tmp_path)
    endpoint = f"tls/localhost:{free_port()}"
    server = Bus(WallClock(), "refused", options=SessionOptions(listen=[endpoint], config=conf["server"]))
    nobody = f"tcp/127.0.0.1:{free_port()}"
    try:
        cases = [(["send", "LOn", "--timeout", "30", "--connect", endpoint], 3,
                  f"hexbench send: cannot connect to {endpoint}: TLS handshake refused (check the CA "
                  "in --zenoh-config)"),
                 (["send", "LOn", "--timeout", "30", "--connect", nobody], 3,
                  f"hexbench send: nothing listens at {nobody}"),
                 (["monitor", "--mode", "client", "--seconds", "30", "--connect", endpoint], 1,
                  f"hexbench monitor: error: cannot connect to {endpoint}: TLS handshake refused"),
                 (["monitor", "--mode", "client", "--seconds", "30", "--connect", nobody], 1,
                  f"hexbench monitor: error: nothing listens at {nobody}")]
        for argv, code, line in cases:
            start = time.monotonic()
            assert main([*argv, "--fleet", "refused"]) == code, argv
            assert time.monotonic() - start < 10, argv  # not the 30 s of --timeout / --seconds
            err = capsys.readouterr().err
            assert err.startswith(line) and len(err.strip().splitlines()) == 1, err
            assert "no fleet or bridge listens" not in err
        # with the CA the same peer reaches the listener (require_connect: it would raise)
        Bus(WallClock(), "refused", options=SessionOptions(connect=[endpoint], config=conf["client"],
                                                           require_connect=True)).close()
    finally:
        server.close()


def test_a_peer_that_reaches_nobody_is_warned_and_keeps_going(capsys):
    nobody = f"tcp/127.0.0.1:{free_port()}"
    assert main(["monitor", "--connect", nobody, "--seconds", "0.1"]) == 0
    assert f"warning: nothing listens at {nobody} (zenoh keeps trying)" in capsys.readouterr().err
