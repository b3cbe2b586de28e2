"""TLS on the control channel and the browser page (``serve --tls-cert/--tls-key``, ``client --tls/--tls-ca``).

The certificates are made here, at test time: a CA, a server certificate it signs for ``localhost`` and
``127.0.0.1``, a second CA the client does not trust, and a certificate for another host name.  Bad files fail
when the server or client is configured, by path; a live TLS session streams; a plaintext client, a client that
does not trust the CA and one that reaches a server under another name fail with an error naming the server and
the reason, and the server goes on serving.
"""

from __future__ import annotations

import asyncio
import datetime
import ipaddress
import socket
import ssl
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from splitrender.cli import main
from splitrender.client.session import ClientConfig, LiveClient
from splitrender.errors import ConfigError
from splitrender.server.server import LiveServer, ServerConfig
from splitrender.transport import ConnectError
from splitrender.transport.tls import client_context, server_context

LOOPBACK = "127.0.0.1"
UNTRUSTED = "TLS certificate verification failed: unable to get local issuer certificate"


@dataclass(frozen=True)
class Pki:
    ca: Path
    cert: Path
    key: Path
    other_ca: Path
    other_key: Path
    encrypted_key: Path
    elsewhere_cert: Path
    """Signed by ``ca`` for ``elsewhere.example`` only (its key is ``key``)."""


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _ca(cn: str) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(_name(cn)).issuer_name(_name(cn)).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(hours=1))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    return cert, key


def _leaf(ca: x509.Certificate, ca_key: ec.EllipticCurvePrivateKey, key: ec.EllipticCurvePrivateKey,
          names: list[x509.GeneralName]) -> x509.Certificate:
    now = datetime.datetime.now(datetime.timezone.utc)
    return (x509.CertificateBuilder().subject_name(_name("splitrender test")).issuer_name(ca.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(hours=1)).not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .add_extension(x509.ExtendedKeyUsage([x509.oid.ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256()))


def _pem_key(key: ec.EllipticCurvePrivateKey, password: bytes | None = None) -> bytes:
    enc = serialization.BestAvailableEncryption(password) if password else serialization.NoEncryption()
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, enc)


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    d = tmp_path_factory.mktemp("pki")
    ca, ca_key = _ca("splitrender test CA")
    other_ca, _ = _ca("someone else's CA")
    key = ec.generate_private_key(ec.SECP256R1())
    cert = _leaf(ca, ca_key, key, [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address(LOOPBACK))])
    elsewhere = _leaf(ca, ca_key, key, [x509.DNSName("elsewhere.example")])
    pem = serialization.Encoding.PEM
    files = {"ca": ca.public_bytes(pem), "cert": cert.public_bytes(pem), "key": _pem_key(key),
             "other_ca": other_ca.public_bytes(pem), "other_key": _pem_key(ec.generate_private_key(ec.SECP256R1())),
             "encrypted_key": _pem_key(key, b"secret"), "elsewhere_cert": elsewhere.public_bytes(pem)}
    for name, data in files.items():
        (d / f"{name}.pem").write_bytes(data)
    return Pki(**{name: d / f"{name}.pem" for name in files})


# ---------------------------------------------------------------------------------------------------- configuration


def test_bad_certificates_keys_and_cas_are_refused_at_configuration_by_path(pki: Pki, tmp_path: Path) -> None:
    garbled = tmp_path / "garbled.pem"
    garbled.write_text("-----BEGIN CERTIFICATE-----\nnot base64 at all\n-----END CERTIFICATE-----\n")
    missing = tmp_path / "missing.pem"
    server_cases = [
        (dict(tls_cert=pki.cert), "--tls-cert: needs --tls-key too (the certificate and its private key)"),
        (dict(tls_key=pki.key), "--tls-key: needs --tls-cert too (the certificate and its private key)"),
        (dict(tls_cert=missing, tls_key=pki.key), f"--tls-cert {missing}: cannot read it: no such file or directory"),
        (dict(tls_cert=tmp_path, tls_key=pki.key), f"--tls-cert {tmp_path}: cannot read it: is a directory"),
        (dict(tls_cert=pki.key, tls_key=pki.key), f"--tls-cert {pki.key}: not a PEM certificate (no 'BEGIN CERTIFICATE' block)"),
        (dict(tls_cert=pki.cert, tls_key=pki.cert), f"--tls-key {pki.cert}: not a PEM private key (no 'PRIVATE KEY' block)"),
        (dict(tls_cert=pki.cert, tls_key=pki.other_key),
         f"--tls-key {pki.other_key}: does not match the certificate in --tls-cert {pki.cert}"),
        (dict(tls_cert=pki.cert, tls_key=pki.encrypted_key),
         f"--tls-key {pki.encrypted_key}: the key is passphrase-protected, which serve cannot prompt for "
         "(write it out unencrypted, e.g. openssl pkey -in KEY -out PLAIN)"),
        (dict(tls_cert=garbled, tls_key=pki.key),
         f"--tls-cert {garbled} / --tls-key {pki.key}: cannot load them (a PEM block that does not decode)"),
    ]
    for kw, message in server_cases:
        with pytest.raises(ConfigError) as info:
            ServerConfig(port=0, udp_port=0, scene="minimal", **kw)  # type: ignore[arg-type]
        assert str(info.value) == message, kw
    client_cases = [
        (dict(tls=True, tls_ca=missing), f"--tls-ca {missing}: cannot read it: no such file or directory"),
        (dict(tls=True, tls_ca=pki.key), f"--tls-ca {pki.key}: not a PEM certificate (no 'BEGIN CERTIFICATE' block)"),
        (dict(tls=True, tls_ca=garbled), f"--tls-ca {garbled}: cannot load its certificates (a PEM block that does not decode)"),
        (dict(tls_ca=pki.ca), f"client tls_ca {pki.ca}: a CA to verify the server by, so it needs tls"),
    ]
    for kw, message in client_cases:
        with pytest.raises(ConfigError) as info:
            ClientConfig(**kw)  # type: ignore[arg-type]
        assert str(info.value) == message, kw
    # what is fine: a matching pair, a PEM CA; verification on, with the host name checked
    assert ServerConfig(port=0, udp_port=0, tls_cert=pki.cert, tls_key=pki.key).tls_context() is not None
    ctx = ClientConfig(tls=True, tls_ca=pki.ca).tls_context()
    assert ctx is not None and ctx.verify_mode == ssl.CERT_REQUIRED and ctx.check_hostname
    assert ClientConfig().tls_context() is None


def test_cli_refuses_tls_options_at_startup(pki: Pki, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for argv, message in (
        (["serve", "--tls-cert", str(pki.cert), "--host", "999.1.1.1"],
         "--tls-cert: needs --tls-key too (the certificate and its private key)"),
        (["serve", "--tls-cert", str(pki.cert), "--tls-key", str(pki.other_key), "--host", "999.1.1.1"],
         f"--tls-key {pki.other_key}: does not match the certificate in --tls-cert {pki.cert}"),
        (["client", "--tls-ca", str(tmp_path / "nope.pem")], f"--tls-ca {tmp_path / 'nope.pem'}: cannot read it: no such file or directory"),
    ):
        assert main(argv) == 2, argv
        assert capsys.readouterr().err == f"splitrender: error: {message}\n"


# ---------------------------------------------------------------------------------------------------- clients


@pytest.fixture
def bare_tls_server(pki: Pki) -> Iterator[int]:
    """A thread that completes TLS handshakes (with ``elsewhere_cert`` on its second connection) and hangs up:
    enough for a client's certificate checks, without a LiveServer."""
    plain = socket.socket()
    plain.bind((LOOPBACK, 0))
    plain.listen()
    plain.settimeout(0.05)
    stop = threading.Event()
    contexts = [server_context(pki.cert, pki.key), server_context(pki.elsewhere_cert, pki.key)]

    def accept() -> None:
        n = 0
        while not stop.is_set():
            try:
                conn, _ = plain.accept()
            except TimeoutError:
                continue
            conn.settimeout(5)
            with conn:
                try:
                    with contexts[min(n, 1)].wrap_socket(conn, server_side=True):
                        pass
                except (ssl.SSLError, OSError):
                    pass
            n += 1

    t = threading.Thread(target=accept, daemon=True)
    t.start()
    yield plain.getsockname()[1]
    stop.set()
    t.join(5)
    plain.close()


def test_cli_client_that_does_not_trust_the_server_exits_2_naming_it(pki: Pki, bare_tls_server: int,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    port = bare_tls_server
    assert main(["client", "--tls", "--port", str(port), "--duration", "1"]) == 2      # the system's CAs
    assert capsys.readouterr().err == f"splitrender: error: cannot connect to {LOOPBACK}:{port}: {UNTRUSTED}\n"
    assert main(["client", "--tls-ca", str(pki.ca), "--port", str(port), "--duration", "1"]) == 2  # elsewhere.example
    assert capsys.readouterr().err == (f"splitrender: error: cannot connect to {LOOPBACK}:{port}: TLS certificate "
                                       f"verification failed: IP address mismatch, certificate is not valid for "
                                       f"'{LOOPBACK}'.\n")


async def test_a_tls_client_against_a_plaintext_server_names_the_reason(pki: Pki) -> None:
    async def plaintext(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.read(100)                      # the ClientHello, read as a control frame ...
        writer.write(b"\x00\x00\x00\x10not a TLS reply")   # ... and answered in plaintext
        await writer.drain()
        writer.close()

    server = await asyncio.start_server(plaintext, LOOPBACK, 0)
    port = server.sockets[0].getsockname()[1]
    async with server:
        with pytest.raises(ConnectError) as info:
            await LiveClient(ClientConfig(port=port, tls=True, tls_ca=pki.ca, duration_s=0.5)).run()
    assert str(info.value) == (f"cannot connect to {LOOPBACK}:{port}: TLS handshake failed: the peer does not speak TLS "
                               "(wrong version number)")


# ---------------------------------------------------------------------------------------------------- live


async def _stream(port: int, tmp: Path, **kw: object) -> dict[str, object]:
    cfg = ClientConfig(server=LOOPBACK, port=port, methods=("video",), width=160, height=90, duration_s=1.0,
                       display_hz=30.0, out_dir=tmp, **kw)  # type: ignore[arg-type]
    result = await asyncio.wait_for(LiveClient(cfg).run(), 30)
    return {"rows": len(result.rows), **result.counters}


async def test_a_tls_session_streams_and_bad_clients_fail_without_stopping_the_server(pki: Pki, tmp_path: Path) -> None:
    cfg = ServerConfig(host=LOOPBACK, port=0, udp_port=0, scene="minimal", methods=("video",), tls_cert=pki.cert,
                       tls_key=pki.key)
    async with LiveServer(cfg) as server:
        serve = asyncio.create_task(server.serve_forever())
        try:
            port = server.tcp_address[1]
            where = f"{LOOPBACK}:{port}"
            with pytest.raises(ConnectError) as info:             # plaintext Hello to a TLS port
                await LiveClient(ClientConfig(port=port, duration_s=0.5)).run()
            assert str(info.value) == (f"{where} closed the connection without answering Hello: if it serves TLS "
                                       "(serve --tls-cert), connect with --tls")
            for ca in (None, pki.other_ca):                       # the system's CAs; someone else's CA
                with pytest.raises(ConnectError) as info:
                    await LiveClient(ClientConfig(port=port, tls=True, tls_ca=ca, duration_s=0.5)).run()
                assert str(info.value) == f"cannot connect to {where}: {UNTRUSTED}", ca
            stats = await _stream(port, tmp_path / "tls", tls=True, tls_ca=pki.ca)
            assert server.sessions_total == 1     # a failed handshake never reaches a session (nor its render worker)
        finally:
            serve.cancel()
            await asyncio.gather(serve, return_exceptions=True)
    # 1 s at 30 Hz: 30 rows and about 30 updates here; half of that on a loaded machine
    assert int(stats["rows"]) >= 15 and int(stats["frames_complete"]) >= 10, stats   # type: ignore[call-overload]
    assert int(stats["rtp_packets"]) > 0, stats                                        # type: ignore[call-overload]


async def test_the_page_and_its_api_over_https(pki: Pki, tmp_path: Path) -> None:
    import aiohttp

    cfg = ServerConfig(host=LOOPBACK, port=0, udp_port=0, scene="minimal", methods=("video",), tls_cert=pki.cert,
                       tls_key=pki.key, webrtc_http=(LOOPBACK, 0), out_dir=tmp_path)
    async with LiveServer(cfg) as server:
        host, port = server.front.address
        trusting = client_context(pki.ca)
        async with aiohttp.ClientSession() as http:
            for name in ("localhost", host):                      # both names the certificate carries
                async with http.get(f"https://{name}:{port}/", ssl=trusting) as r:
                    assert r.status == 200 and "main.js" in await r.text()
            async with http.get(f"https://{host}:{port}/api/info", ssl=trusting) as r:
                assert r.status == 200 and (await r.json())["methods"] == ["video"]
            with pytest.raises(aiohttp.ClientConnectorCertificateError) as info:   # verification is on by default
                async with http.get(f"https://{host}:{port}/api/info"):
                    pass
            assert "unable to get local issuer certificate" in str(info.value)
            with pytest.raises(aiohttp.ClientError):              # no plaintext page on the TLS port
                async with http.get(f"http://{host}:{port}/api/info") as r:
                    await r.read()
