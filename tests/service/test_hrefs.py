"""Inputs by href on another host (``TREESIM_ALLOW_REMOTE_HREFS``): the service must not
become a way into its own network (SSRF). An href whose host resolves to a loopback,
link-local, private or multicast address is refused (422 problem+json), also after a
redirect, unless ``TREESIM_REMOTE_HREF_HOSTS`` lists the host; only http(s); the download
is bounded in size (``TREESIM_MAX_UPLOAD_BYTES``) and time
(``TREESIM_REMOTE_HREF_TIMEOUT_S``).

No test reaches the network: the servers are tiny HTTP servers on this machine's loopback,
and the addresses the guard must refuse are refused before any connection (each server
counts the requests it got). Oracles: the address ranges of RFC 1918 / 3927 / 4291 / 6598,
and the bytes and requests the test's own servers saw.
"""

from __future__ import annotations

import http.server
import shutil
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

import treesim.service.api.uploads as uploads
from treesim.service.api.uploads import blocked_address
from treesim.service.app import create_app
from treesim.service.settings import Settings

from .conftest import BUNDLED_CLOUD

PROBLEM = "application/problem+json"
CLOUD = BUNDLED_CLOUD.read_bytes()
N_POINTS = sum(1 for line in BUNDLED_CLOUD.read_text().splitlines() if line.strip())


class Served:
    """A tiny HTTP server on 127.0.0.1: ``routes`` maps a path to a function of the
    handler that answers it; every request's (path, Host header) is kept in ``seen``."""

    def __init__(self, routes: dict[str, Callable[[http.server.BaseHTTPRequestHandler], None]]):
        self.seen: list[tuple[str, str]] = []
        seen, table = self.seen, routes

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                seen.append((self.path, self.headers.get("Host", "")))
                answer = table.get(self.path)
                if answer is None:
                    self.send_error(404, "no such file")
                    return
                answer(self)

            def log_message(self, *args) -> None:
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.port = self.httpd.server_address[1]
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def _file(data: bytes, *, length: bool = True) -> Callable:
    def answer(h: http.server.BaseHTTPRequestHandler) -> None:
        h.send_response(200)
        h.send_header("Content-Type", "text/plain")
        if length:
            h.send_header("Content-Length", str(len(data)))
        else:
            h.close_connection = True  # the body ends when the connection does
        h.end_headers()
        h.wfile.write(data)

    return answer


def _redirect(location: str) -> Callable:
    def answer(h: http.server.BaseHTTPRequestHandler) -> None:
        h.send_response(302)
        h.send_header("Location", location)
        h.send_header("Content-Length", "0")
        h.end_headers()

    return answer


def _drip(n: int, every_s: float) -> Callable:
    """Headers at once, then one byte every ``every_s`` seconds (``n`` bytes)."""

    def answer(h: http.server.BaseHTTPRequestHandler) -> None:
        h.send_response(200)
        h.send_header("Content-Length", str(n))
        h.end_headers()
        try:
            for _ in range(n):
                h.wfile.write(b"0")
                h.wfile.flush()
                time.sleep(every_s)
        except OSError:
            pass  # the service hung up: as it should

    return answer


@pytest.fixture
def served() -> Iterator[Callable[..., Served]]:
    started: list[Served] = []

    def start(routes: dict) -> Served:
        s = Served(routes)
        started.append(s)
        return s

    yield start
    for s in started:
        s.close()


def _client(tmp_path: Path, **kw) -> TestClient:
    base = dict(
        data_dir=tmp_path / "data",
        workers=0,
        api_token=None,
        database_url=None,
        allow_remote_hrefs=True,
        remote_href_timeout_s=5.0,
    )
    return TestClient(create_app(Settings(**{**base, **kw})))


def _execute(client: TestClient, href: str):
    return client.post(
        "/v1/processes/reconstruct/execution", json={"inputs": {"cloud": {"href": href}}}
    )


def _problem(r, status: int, slug: str) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    body = r.json()
    assert body["type"] == f"/problems#{slug}", body
    assert body["status"] == status and body["field"] == "inputs.cloud", body
    return body


def _parts(tmp_path: Path) -> list[Path]:
    return list((tmp_path / "data").rglob("*.part"))


# -- the addresses ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("address", "why"),
    [
        ("127.0.0.1", "loopback"),
        ("127.255.0.9", "loopback"),
        ("::1", "loopback"),
        ("169.254.169.254", "link-local"),  # a cloud's metadata service
        ("fe80::1", "link-local"),
        ("10.1.2.3", "private"),
        ("172.16.0.1", "private"),
        ("192.168.1.1", "private"),
        ("fd12:3456::1", "private"),
        ("224.0.0.1", "multicast"),
        ("ff02::1", "multicast"),
        ("0.0.0.0", "unspecified"),
        ("100.64.0.1", "not public"),  # carrier-grade NAT (RFC 6598)
        ("::ffff:127.0.0.1", "loopback"),  # IPv4-mapped: judged as the IPv4 address
        ("::ffff:10.0.0.1", "private"),
        ("8.8.8.8", None),
        ("93.184.216.34", None),
        ("2001:4860:4860::8888", None),
    ],
)
def test_which_addresses_are_blocked(address, why):
    assert blocked_address(address) == why


# -- refused, with nothing fetched ------------------------------------------------------------
def test_hrefs_to_the_service_s_own_network_are_a_422_and_nothing_is_fetched(tmp_path, served):
    srv = served({"/tree.xyz": _file(CLOUD)})
    hrefs = [
        f"http://127.0.0.1:{srv.port}/tree.xyz",
        f"http://localhost:{srv.port}/tree.xyz",  # a name: judged by what it resolves to
        f"http://[::ffff:127.0.0.1]:{srv.port}/tree.xyz",
        "http://169.254.169.254/latest/meta-data/iam/security-credentials/",
        "http://10.0.0.7/tree.xyz",
        "http://192.168.0.10:8080/tree.xyz",
        "http://224.0.0.1/tree.xyz",
        f"http://0.0.0.0:{srv.port}/tree.xyz",
    ]
    with _client(tmp_path) as client:
        for href in hrefs:
            t0 = time.monotonic()
            body = _problem(_execute(client, href), 422, "remote-input-blocked")
            assert time.monotonic() - t0 < 2.0, href  # refused, not tried and timed out
            assert "TREESIM_REMOTE_HREF_HOSTS" in body["detail"], body
        assert client.get("/v1/uploads").json()["uploads"] == []
        assert client.get("/v1/jobs").json()["jobs"] == []
    assert srv.seen == []  # no request reached the server
    assert _parts(tmp_path) == []


def test_a_host_with_one_private_address_among_public_ones_is_refused(tmp_path, monkeypatch):
    """Every address a name resolves to is checked, not only the first."""
    real = socket.getaddrinfo

    def fake(host, port, *args, **kwargs):
        if host == "files.example":
            return [
                (socket.AF_INET, socket.SOCK_STREAM, 6, "", ("93.184.216.34", port)),
                (socket.AF_INET, socket.SOCK_STREAM, 6, "", ("10.0.0.7", port)),
            ]
        return real(host, port, *args, **kwargs)

    monkeypatch.setattr(uploads.socket, "getaddrinfo", fake)
    with _client(tmp_path) as client:
        body = _problem(
            _execute(client, "http://files.example/tree.xyz"), 422, "remote-input-blocked"
        )
    assert "10.0.0.7" in body["detail"] and "private" in body["detail"]


def test_a_redirect_into_the_service_s_network_is_refused(tmp_path, served):
    """An allowed host's redirect to another (loopback, not listed) host is checked as an
    href of its own: refused, and the redirect's target never asked."""
    target = served({"/secret": _file(b"secret\n")})
    hop = served({"/tree.xyz": _redirect(f"http://localhost:{target.port}/secret")})
    with _client(tmp_path, remote_href_hosts=["127.0.0.1"]) as client:
        body = _problem(
            _execute(client, f"http://127.0.0.1:{hop.port}/tree.xyz"), 422, "remote-input-blocked"
        )
    assert "localhost" in body["detail"]
    assert [p for p, _ in hop.seen] == ["/tree.xyz"] and target.seen == []


def test_only_http_and_https(tmp_path):
    with _client(tmp_path, remote_href_hosts=["127.0.0.1"]) as client:
        for href in ("file:///etc/passwd", "ftp://127.0.0.1/tree.xyz", "gopher://127.0.0.1/x"):
            r = _execute(client, href)
            assert r.status_code == 400 and "http(s)" in r.json()["detail"], r.text


# -- let through by the operator's list, within the limits -------------------------------------
def test_a_listed_host_is_fetched_and_kept_as_an_upload(tmp_path, served):
    srv = served({"/tree.xyz": _file(CLOUD), "/moved.xyz": _redirect("/tree.xyz")})
    with _client(tmp_path, remote_href_hosts=["127.0.0.1"]) as client:
        r = _execute(client, f"http://127.0.0.1:{srv.port}/moved.xyz")
        assert r.status_code == 201, r.text
        ups = client.get("/v1/uploads").json()["uploads"]
        assert [u["filename"] for u in ups] == ["moved.xyz"]
        assert ups[0]["n_points"] == N_POINTS  # the served file, whole
        assert r.json()["inputs"]["cloud"]["upload"] == ups[0]["id"]
    assert [p for p, _ in srv.seen] == ["/moved.xyz", "/tree.xyz"]  # the redirect followed


def test_the_connection_goes_to_the_address_checked_with_the_host_s_name(
    tmp_path, served, monkeypatch
):
    """The name is resolved once: the connection is made to the address that was checked
    (a second lookup could answer another), and the request still names the host."""
    srv = served({"/tree.xyz": _file(CLOUD)})
    real = socket.getaddrinfo
    lookups: list[str] = []

    def fake(host, port, *args, **kwargs):
        if host == "lab.example":
            lookups.append(host)
            return [(socket.AF_INET, socket.SOCK_STREAM, 6, "", ("127.0.0.1", port))]
        return real(host, port, *args, **kwargs)

    monkeypatch.setattr(uploads.socket, "getaddrinfo", fake)
    with _client(tmp_path, remote_href_hosts=["lab.example"]) as client:
        r = _execute(client, f"http://lab.example:{srv.port}/tree.xyz")
        assert r.status_code == 201, r.text
    assert lookups == ["lab.example"]
    assert srv.seen == [("/tree.xyz", f"lab.example:{srv.port}")]


@pytest.mark.skipif(shutil.which("openssl") is None, reason="makes its certificate with openssl")
def test_https_checks_the_host_s_certificate_on_the_pinned_connection(
    tmp_path, served, monkeypatch
):
    """An https href of a listed host, resolved to this machine: the TLS handshake names
    the host (SNI) and its certificate is verified against that name although the
    connection goes to the checked address: refused while the certificate's issuer is
    unknown, fetched once the service trusts it."""
    import ssl
    import subprocess

    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
         "-keyout", str(key), "-out", str(cert), "-subj", "/CN=lab.example",
         "-addext", "subjectAltName=DNS:lab.example"],
        check=True, capture_output=True,
    )  # fmt: skip
    srv = served({"/tree.xyz": _file(CLOUD)})
    tls = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    tls.load_cert_chain(cert, key)
    srv.httpd.socket = tls.wrap_socket(srv.httpd.socket, server_side=True)
    real = socket.getaddrinfo

    def fake(host, port, *args, **kwargs):
        if host == "lab.example":
            return [(socket.AF_INET, socket.SOCK_STREAM, 6, "", ("127.0.0.1", port))]
        return real(host, port, *args, **kwargs)

    monkeypatch.setattr(uploads.socket, "getaddrinfo", fake)
    href = f"https://lab.example:{srv.port}/tree.xyz"
    with _client(tmp_path, remote_href_hosts=["lab.example"]) as client:
        body = _problem(_execute(client, href), 400, "bad-request")
        assert "CERTIFICATE_VERIFY_FAILED" in body["detail"], body
        assert client.get("/v1/uploads").json()["uploads"] == []
        monkeypatch.setenv("SSL_CERT_FILE", str(cert))  # the service now trusts its issuer
        r = _execute(client, href)
        assert r.status_code == 201, r.text
        assert client.get("/v1/uploads").json()["uploads"][0]["n_points"] == N_POINTS
    assert srv.seen == [("/tree.xyz", f"lab.example:{srv.port}")]  # only the trusted try


@pytest.mark.parametrize("length", [True, False], ids=["content-length", "until-close"])
def test_a_remote_file_past_the_upload_limit_is_a_413_and_nothing_is_kept(tmp_path, served, length):
    limit = 100_000
    srv = served({"/big.xyz": _file(b"0 0 0\n" * 50_000, length=length)})  # 300 kB
    with _client(tmp_path, remote_href_hosts=["127.0.0.1"], max_upload_bytes=limit) as client:
        body = _problem(
            _execute(client, f"http://127.0.0.1:{srv.port}/big.xyz"), 413, "payload-too-large"
        )
        assert f"{limit:,}" in body["detail"]
        assert client.get("/v1/uploads").json()["uploads"] == []
    assert _parts(tmp_path) == []


def test_a_remote_file_that_trickles_past_the_time_limit_is_refused(tmp_path, served):
    """Each byte arrives well within any read timeout, but the whole would take 20 s: the
    download's own deadline stops it."""
    srv = served({"/slow.xyz": _drip(100, 0.2)})
    with _client(tmp_path, remote_href_hosts=["127.0.0.1"], remote_href_timeout_s=1.0) as client:
        t0 = time.monotonic()
        body = _problem(
            _execute(client, f"http://127.0.0.1:{srv.port}/slow.xyz"), 400, "bad-request"
        )
        took_s = time.monotonic() - t0
        assert client.get("/v1/uploads").json()["uploads"] == []
    assert "TREESIM_REMOTE_HREF_TIMEOUT_S" in body["detail"], body
    assert 1.0 <= took_s < 5.0, took_s
    assert _parts(tmp_path) == []
