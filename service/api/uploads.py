"""``/v1/uploads``: clouds, meshes and plots (zip archives), streamed to disk, checked,
stored once by content."""

from __future__ import annotations

import asyncio
import hashlib
import http.client
import ipaddress
import os
import socket
import ssl
import time
import unicodedata
import uuid
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any
from urllib.parse import SplitResult, urljoin, urlsplit

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from treesim.errors import EmptyInputError

from ..plots import UNPACK_FACTOR
from ..problems import ServiceProblem
from ..schemas import Link, UploadList, UploadOut, iso
from .deps import BaseDep, SettingsDep, StoreDep, UserDep
from .responses import PROBLEM_RESPONSES

router = APIRouter(tags=["uploads"])


def check_filename(name: str | None) -> str:
    """The upload's name, which is metadata only: a plain file name, never a path."""
    if name is None or not name.strip():
        return "upload"
    name = unicodedata.normalize("NFC", name.strip())
    bad = (
        "/" in name
        or "\\" in name
        or name in (".", "..")
        or name.startswith("..")
        or any(unicodedata.category(c).startswith("C") for c in name)
        or len(name.encode("utf-8")) > 255
    )
    if bad:
        raise ServiceProblem(
            "invalid-parameter",
            f"filename {name!r} must be a plain file name (no folders, no '..', no control "
            "characters, at most 255 bytes); it is kept as a label only",
            field="filename",
        )
    return name


def upload_out(rec: dict[str, Any], base: str = "") -> UploadOut:
    info = rec["info"] or {}
    lo, hi = info.get("bounds", [[0, 0, 0], [0, 0, 0]])
    return UploadOut(
        id=rec["id"],
        filename=rec["filename"],
        format=rec["format"],
        kind=rec["kind"],
        size_bytes=rec["size_bytes"],
        sha256=rec["sha256"],
        n_points=rec["n_points"],
        n_triangles=rec["n_triangles"],
        n_trees=info.get("n_trees"),
        bounds={"min": list(lo), "max": list(hi)},
        fields=list(info.get("fields", [])),
        created=iso(rec["created"]),
        links=[
            Link(
                href=f"{base}/v1/uploads/{rec['id']}",
                rel="self",
                type="application/json",
                title="this upload: its href is an input of a process",
            )
        ],
    )


async def stall_limited(chunks: AsyncIterator[bytes], stall_s: float) -> AsyncIterator[bytes]:
    """The body's chunks, ending in a 408 problem when none arrives for ``stall_s``
    seconds (``TREESIM_UPLOAD_STALL_S``): a stalled client holds no connection and no
    ``.part`` file for long."""
    it = chunks.__aiter__()
    while True:
        try:
            async with asyncio.timeout(stall_s):
                chunk = await it.__anext__()
        except StopAsyncIteration:
            return
        except TimeoutError:
            raise ServiceProblem(
                "upload-stalled",
                f"no bytes of the upload arrived for {stall_s:g} s (TREESIM_UPLOAD_STALL_S)",
            ) from None
        yield chunk


def _tmp_dir(data_dir: Path) -> Path:
    d = data_dir / "uploads" / "tmp"
    d.mkdir(parents=True, exist_ok=True)
    return d


@router.post(
    "/uploads",
    status_code=201,
    response_model=UploadOut,
    summary="Upload a point cloud, a mesh or a plot archive (the raw file as the body)",
    responses={
        200: {"model": UploadOut, "description": "the same content was uploaded before"},
        **PROBLEM_RESPONSES(411, 413, 415, 422, 507),
    },
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}
            },
        }
    },
)
async def create_upload(
    request: Request,
    response: Response,
    settings: SettingsDep,
    base: BaseDep,
    user: UserDep,
    filename: Annotated[
        str | None, Query(max_length=1000, description="the file's name (a label only)")
    ] = None,
) -> UploadOut:
    """Stream the body to disk (never held in memory), with its SHA-256; sniff its format
    from the bytes (LAS, LAZ, PLY, OBJ, XYZ, E57; a zip archive is a plot: ``plot.toml`` at
    its root or in its top folder, with its trees CSV and the trees' files), open and check
    it; store it once per content. 413 past ``TREESIM_MAX_UPLOAD_BYTES``, 415 for a format
    treesim does not read, 422 for a broken file or plot (a plot archive may unpack to 4 x
    the limit); nothing is kept on error."""
    name = check_filename(filename)
    limit = settings.max_upload_bytes
    length = request.headers.get("content-length")
    if length is not None:
        try:
            declared = int(length)
        except ValueError:
            raise ServiceProblem("bad-request", "Content-Length is not a number") from None
        if declared > limit:
            raise ServiceProblem(
                "payload-too-large",
                f"the upload is {declared:,} bytes; the limit is {limit:,} "
                "(TREESIM_MAX_UPLOAD_BYTES)",
            )
    elif "chunked" not in request.headers.get("transfer-encoding", "").lower():
        raise ServiceProblem("length-required", "send Content-Length or a chunked body")
    tmp = _tmp_dir(settings.data_dir) / f"{uuid.uuid4().hex}.part"
    digest = hashlib.sha256()
    size = 0
    try:
        with open(tmp, "wb") as fh:
            async for chunk in stall_limited(request.stream(), settings.upload_stall_s):
                size += len(chunk)
                if size > limit:
                    raise ServiceProblem(
                        "payload-too-large",
                        f"the upload exceeds the limit of {limit:,} bytes "
                        "(TREESIM_MAX_UPLOAD_BYTES)",
                    )
                digest.update(chunk)
                fh.write(chunk)
        rec, created = await keep(
            request.app.state, tmp, size, digest.hexdigest(), name, filename, owner=user.owns_as
        )
    finally:
        tmp.unlink(missing_ok=True)
    response.status_code = 201 if created else 200
    response.headers["Location"] = f"/v1/uploads/{rec['id']}"
    return upload_out(rec, base)


async def keep(
    state: Any,
    tmp: Path,
    size: int,
    sha: str,
    name: str,
    filename: str | None,
    *,
    owner: str | None = None,
) -> tuple[dict[str, Any], bool]:
    """Check a file received into ``tmp`` (``size`` bytes, SHA-256 ``sha``) and store it
    as an upload, once per content: (its record, whether it is new). ``owner``: the user
    who sent it (None on an open service)."""
    settings, store = state.settings, state.store
    if size == 0:
        raise EmptyInputError(f"{name}: the body is empty; send the file's bytes")
    info = await state.inspector.inspect(
        tmp, name if filename else None, max_unpacked=UNPACK_FACTOR * settings.max_upload_bytes
    )
    rel = Path("uploads") / sha[:2] / f"{sha}{info['suffix']}"
    final = settings.data_dir / rel

    def place() -> None:
        final.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, final)

    record = {
        "sha256": sha,
        "filename": name,
        "format": info["format"],
        "kind": info["kind"],
        "size_bytes": size,
        "n_points": info.get("n_points"),
        "n_triangles": info.get("n_triangles"),
        "info": {
            "bounds": info["bounds"],
            "fields": list(info.get("fields", [])),
            **({"n_trees": info["n_trees"]} if "n_trees" in info else {}),
        },
        "path": rel.as_posix(),
    }
    return await run_in_threadpool(lambda: store.add_upload(record, place, owner=owner))


async def fetch_remote(
    state: Any, url: str, field: str, *, owner: str | None = None
) -> dict[str, Any]:
    """Download ``url`` (an input's href on another host, where
    ``TREESIM_ALLOW_REMOTE_HREFS`` allows it) and keep it as an upload, within the
    upload limit and ``TREESIM_REMOTE_HREF_TIMEOUT_S``; its record. An href whose host
    resolves to a non-public address is refused (:func:`remote_address`)."""
    settings = state.settings
    limit = settings.max_upload_bytes
    tmp = _tmp_dir(settings.data_dir) / f"{uuid.uuid4().hex}.part"
    last = url.split("?", 1)[0].rstrip("/").rsplit("/", 1)[-1]
    try:
        name = check_filename(last or None)
    except ServiceProblem:
        name = "remote"
    guard = RemoteGuard(
        frozenset(settings.remote_href_hosts), settings.remote_href_timeout_s, limit
    )
    try:
        size, sha = await run_in_threadpool(guard.download, url, tmp, field)
        rec, _ = await keep(state, tmp, size, sha, name, name, owner=owner)
    finally:
        tmp.unlink(missing_ok=True)
    return rec


#: Redirects a remote href may take; every hop is checked as the href itself.
MAX_REDIRECTS = 5


def blocked_address(address: str) -> str | None:
    """Why a request must not make the service connect to ``address``: it is loopback,
    link-local (the cloud's metadata service, 169.254.169.254), private, multicast,
    unspecified, reserved or otherwise not public; None for a public address. An IPv6
    address that maps an IPv4 one is judged as that.

    Examples
    --------
    >>> blocked_address("169.254.169.254"), blocked_address("::ffff:10.1.2.3")
    ('link-local', 'private')
    >>> blocked_address("93.184.216.34") is None
    True
    """
    ip = ipaddress.ip_address(address.split("%", 1)[0])  # an IPv6 zone is no part of it
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    for why, bad in (
        ("loopback", ip.is_loopback),
        ("link-local", ip.is_link_local),
        ("multicast", ip.is_multicast),
        ("unspecified", ip.is_unspecified),
        ("private", ip.is_private),
        ("reserved", ip.is_reserved),
    ):
        if bad:
            return why
    return None if ip.is_global else "not public"


class RemoteGuard:
    """How the service fetches a remote href: http(s) only; the host resolved once and
    every address it resolves to public, unless the host is in ``allowed_hosts``
    (``TREESIM_REMOTE_HREF_HOSTS``); the connection made to the address checked (a
    second lookup cannot swap it); redirects followed, each checked the same way; at most
    ``limit_bytes``, all within ``timeout_s``."""

    def __init__(self, allowed_hosts: frozenset[str], timeout_s: float, limit_bytes: int):
        self.allowed_hosts = allowed_hosts
        self.timeout_s = float(timeout_s)
        self.limit_bytes = int(limit_bytes)

    def address(self, url: str, field: str) -> tuple[SplitResult, str]:
        """The href's parts and the address to connect to; a problem when it is not an
        http(s) URL (400), cannot be resolved (400) or resolves to an address the
        service does not fetch from (422 ``remote-input-blocked``)."""
        parts = urlsplit(url)
        try:
            port = parts.port or {"http": 80, "https": 443}.get(parts.scheme)
        except ValueError:
            port = None
        host = (parts.hostname or "").lower()
        if parts.scheme not in ("http", "https") or not host or port is None:
            raise ServiceProblem(
                "bad-request", f"{field}: href {url!r} is not an http(s) URL", field=field
            )
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        except (OSError, UnicodeError) as exc:
            raise ServiceProblem(
                "bad-request", f"{field}: could not resolve the host of {url}: {exc}", field=field
            ) from None
        addresses = list(dict.fromkeys(str(info[4][0]) for info in infos))
        if host not in self.allowed_hosts:
            for a in addresses:
                why = blocked_address(a)
                if why:
                    raise ServiceProblem(
                        "remote-input-blocked",
                        f"{field}: href {url!r} names {host}, a {why} address ({a}); the "
                        "service fetches only from public hosts and those its operator "
                        "lists in TREESIM_REMOTE_HREF_HOSTS",
                        field=field,
                    )
        return parts, addresses[0]

    def download(self, url: str, tmp: Path, field: str) -> tuple[int, str]:
        """Stream ``url`` into ``tmp`` (redirects followed, each hop checked): (size,
        SHA-256)."""
        deadline = time.monotonic() + self.timeout_s
        for _ in range(MAX_REDIRECTS + 1):
            parts, address = self.address(url, field)
            try:
                got = self._get(parts, address, tmp, field, deadline)
            except (OSError, http.client.HTTPException) as exc:
                if time.monotonic() >= deadline or isinstance(exc, TimeoutError):
                    raise self._timeout(url, field) from None
                raise ServiceProblem(
                    "bad-request", f"{field}: could not fetch {url}: {exc}", field=field
                ) from None
            if isinstance(got, str):  # a redirect
                url = urljoin(url, got)
                continue
            return got
        raise ServiceProblem(
            "bad-request", f"{field}: {url} redirects more than {MAX_REDIRECTS} times", field=field
        )

    def _timeout(self, url: str, field: str) -> ServiceProblem:
        return ServiceProblem(
            "bad-request",
            f"{field}: {url} did not arrive within {self.timeout_s:g} s "
            "(TREESIM_REMOTE_HREF_TIMEOUT_S)",
            field=field,
        )

    def _get(
        self, parts: SplitResult, address: str, tmp: Path, field: str, deadline: float
    ) -> tuple[int, str] | str:
        """One GET to ``address``: (size, SHA-256) of the body written to ``tmp``, or a
        redirect's Location."""
        left = max(deadline - time.monotonic(), 0.001)
        cls = _PinnedHTTPS if parts.scheme == "https" else _PinnedHTTP
        conn = cls(parts.hostname or "", parts.port, address, left)
        url = parts.geturl()
        try:
            target = (parts.path or "/") + (f"?{parts.query}" if parts.query else "")
            headers = {"User-Agent": "treesim", "Accept-Encoding": "identity"}
            conn.request("GET", target, headers=headers)
            r = conn.getresponse()
            if r.status in (301, 302, 303, 307, 308) and r.getheader("Location"):
                return str(r.getheader("Location"))
            if r.status != 200:
                raise ServiceProblem(
                    "bad-request",
                    f"{field}: could not fetch {url}: the server answered HTTP {r.status} "
                    f"{r.reason}",
                    field=field,
                )
            declared = r.getheader("Content-Length")
            if declared and declared.isdigit() and int(declared) > self.limit_bytes:
                raise self._too_large(url, field)
            return self._body(r, conn, tmp, url, field, deadline)
        finally:
            conn.close()

    def _too_large(self, url: str, field: str) -> ServiceProblem:
        return ServiceProblem(
            "payload-too-large",
            f"{field}: {url} is larger than the upload limit of {self.limit_bytes:,} bytes "
            "(TREESIM_MAX_UPLOAD_BYTES)",
            field=field,
        )

    def _body(
        self, r: Any, conn: Any, tmp: Path, url: str, field: str, deadline: float
    ) -> tuple[int, str]:
        digest = hashlib.sha256()
        size = 0
        with open(tmp, "wb") as fh:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise self._timeout(url, field)
                if conn.sock is not None:
                    conn.sock.settimeout(left)  # a read waits no longer than what is left
                chunk = r.read1(1 << 20)
                if not chunk:
                    return size, digest.hexdigest()
                size += len(chunk)
                if size > self.limit_bytes:
                    raise self._too_large(url, field)
                digest.update(chunk)
                fh.write(chunk)


class _PinnedHTTP(http.client.HTTPConnection):
    """An HTTP connection to ``address`` (checked) for ``host`` (its Host header)."""

    def __init__(self, host: str, port: int | None, address: str, timeout: float) -> None:
        super().__init__(host, port, timeout=timeout)
        self._address = address

    def connect(self) -> None:
        self.sock = socket.create_connection((self._address, self.port), self.timeout)


class _PinnedHTTPS(http.client.HTTPSConnection):
    """An HTTPS connection to ``address`` (checked); the certificate checked for
    ``host``."""

    def __init__(self, host: str, port: int | None, address: str, timeout: float) -> None:
        super().__init__(host, port, timeout=timeout, context=ssl.create_default_context())
        self._address = address

    def connect(self) -> None:
        sock = socket.create_connection((self._address, self.port), self.timeout)
        self.sock = self._context.wrap_socket(sock, server_hostname=self.host)


@router.get("/uploads", response_model=UploadList, summary="List uploads, newest first")
def list_uploads(
    store: StoreDep,
    base: BaseDep,
    user: UserDep,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> UploadList:
    rows = store.list_uploads(limit, offset, owner=user.owner)
    return UploadList(uploads=[upload_out(r, base) for r in rows])


@router.get(
    "/uploads/{upload_id}",
    response_model=UploadOut,
    responses=PROBLEM_RESPONSES(404),
    summary="One upload",
)
def get_upload(upload_id: str, store: StoreDep, base: BaseDep, user: UserDep) -> UploadOut:
    rec = store.upload(upload_id, owner=user.owner)
    if rec is None:
        raise ServiceProblem("not-found", f"no upload {upload_id!r}", field="upload_id")
    return upload_out(rec, base)


@router.delete(
    "/uploads/{upload_id}",
    status_code=204,
    responses=PROBLEM_RESPONSES(404, 409),
    summary="Delete an upload (refused while a job uses it)",
)
def delete_upload(
    upload_id: str, store: StoreDep, settings: SettingsDep, user: UserDep
) -> Response:
    def remove(rec: dict[str, Any]) -> None:
        (settings.data_dir / rec["path"]).unlink(missing_ok=True)

    rec, users = store.delete_upload(upload_id, remove, owner=user.owner)
    if rec is None:
        raise ServiceProblem("not-found", f"no upload {upload_id!r}", field="upload_id")
    if users:
        raise ServiceProblem(
            "conflict",
            f"upload {upload_id} is an input of {len(users)} job(s) that have not finished "
            f"({', '.join(users[:5])}); dismiss them or wait",
            jobs=users,
        )
    return Response(status_code=204)
