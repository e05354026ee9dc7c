"""Dependencies of the API's routes, as ``Annotated`` aliases."""

from __future__ import annotations

import base64
import hashlib
import hmac
import os
import secrets
import time
import tomllib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request

from ..jobs.store import Store
from ..problems import ServiceProblem
from ..settings import Settings

#: The jobs page's session cookie (HttpOnly, SameSite=Strict: set by the server from a
#: token sent once to ``POST /session``; JavaScript never reads it). It opens reading
#: requests only, so that a browser can follow links to reports.
SESSION_COOKIE = "treesim_session"
#: How long a session lasts (s).
SESSION_S = 12 * 3600


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_base(request: Request) -> str:
    """The service's own base URL as the client reached it (no trailing slash): links are
    absolute, and an input's href naming it is one of this service's files."""
    return str(request.base_url).rstrip("/")


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
BaseDep = Annotated[str, Depends(get_base)]


@dataclass(frozen=True)
class User:
    """Who sent a request: a named user (``role`` ``"user"`` or ``"admin"``).

    Examples
    --------
    >>> User("ana", "user").owner, User("root", "admin").owner
    ('ana', None)
    """

    name: str
    role: str

    @property
    def owns_as(self) -> str | None:
        """The name recorded as the owner of what the user makes (None on an open service)."""
        return self.name or None

    @property
    def owner(self) -> str | None:
        """The owner the store narrows to: the user's name, or None (everything) for an
        admin."""
        return None if self.role == "admin" else self.name


#: Who a request is from while no token is set: anyone, seeing everything (an open service).
OPEN = User("", "admin")
ROLES = ("user", "admin")


def hash_token(token: str) -> str:
    """A token's SHA-256 in hex, as the tokens file keeps it (``token_sha256``).

    The same in a shell: ``printf %s "$TOKEN" | sha256sum`` (the first field).

    Examples
    --------
    >>> hash_token("secret")[:16]
    '2bb80d537b1da3e3'
    """
    return hashlib.sha256(token.encode()).hexdigest()


def load_tokens(path: Path) -> dict[str, User]:
    """The tokens file (TOML): token hash → user. Each table is a user::

        [ana]
        token_sha256 = "<64 hex digits>"
        role = "user"          # or "admin"

    Raises :class:`~treesim.errors.InputFormatError` naming the file and the user when an
    entry is malformed, so that the service refuses to start rather than lock people out.

    Examples
    --------
    >>> load_tokens(Path("tokens.toml"))  # doctest: +SKIP
    {'2bb8…': User(name='ana', role='user')}
    """
    from treesim.errors import InputFormatError

    try:
        doc = tomllib.loads(path.read_text("utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputFormatError(f"tokens file {path}: cannot read it: {exc}") from None
    users: dict[str, User] = {}
    for name, entry in doc.items():
        digest = entry.get("token_sha256") if isinstance(entry, dict) else None
        role = entry.get("role", "user") if isinstance(entry, dict) else None
        if not isinstance(digest, str) or len(digest) != 64 or role not in ROLES:
            raise InputFormatError(
                f"tokens file {path}: user {name!r} needs token_sha256 (64 hex digits) and "
                f"role 'user' or 'admin'"
            )
        try:
            bytes.fromhex(digest)
        except ValueError:
            raise InputFormatError(
                f"tokens file {path}: user {name!r}: token_sha256 is not hexadecimal"
            ) from None
        if len(name) > 64:
            raise InputFormatError(f"tokens file {path}: user name {name[:20]!r}… is too long")
        users[digest.lower()] = User(name, role)
    return users


@lru_cache(maxsize=8)
def _tokens_cached(path: Path, mtime_ns: int) -> dict[str, User]:
    return load_tokens(path)


def known_tokens(settings: Settings) -> dict[str, User] | None:
    """Token hash → user, from the tokens file (re-read when it changes) and the single
    ``api_token`` (an admin named ``admin``); None when neither is set (an open service)."""
    users: dict[str, User] = {}
    if settings.tokens_file is not None:
        path = settings.tokens_file
        try:
            mtime = path.stat().st_mtime_ns
        except OSError:
            mtime = -1
        users.update(_tokens_cached(path, mtime))
    token = settings.token()
    if token is not None:
        users[hash_token(token)] = User("admin", "admin")
    if not users and settings.tokens_file is None and token is None:
        return None
    return users


def _given_token(request: Request) -> str | None:
    auth = request.headers.get("authorization", "")
    scheme, _, value = auth.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    return None


def find_user(users: dict[str, User], token: str) -> User | None:
    """The user whose token hash matches ``token``'s, compared in constant time against
    every entry (no early exit).

    Examples
    --------
    >>> find_user({hash_token("s3"): User("ana", "user")}, "s3")
    User(name='ana', role='user')
    >>> find_user({hash_token("s3"): User("ana", "user")}, "s4") is None
    True
    """
    digest = hash_token(token).encode()
    found = None
    for h, user in users.items():
        if hmac.compare_digest(digest, h.encode()):
            found = user
    return found


def require_token(request: Request) -> User:
    """Who sent the request. With a token set (``TREESIM_API_TOKEN`` or
    ``TREESIM_TOKENS_FILE``), every ``/v1`` request needs ``Authorization: Bearer <token>``
    (or, reading, the jobs page's session cookie); no token set: anyone, seeing all."""
    settings = request.app.state.settings
    users = known_tokens(settings)
    if users is None:
        request.state.user = OPEN
        return OPEN
    user = None
    given = _given_token(request)
    if given is not None:
        user = find_user(users, given)
    else:
        user = session_user(request, users)
    if user is None:
        raise ServiceProblem(
            "unauthorized",
            "missing or wrong token: send 'Authorization: Bearer <your token>'",
            headers={"WWW-Authenticate": 'Bearer realm="treesim"'},
        )
    request.state.user = user
    return user


def _session_key(settings: Settings) -> bytes:
    """The key sessions are signed with: a random file in the data folder (0600), made
    once, shared by every process of the service."""
    path = settings.data_dir / "session.key"
    try:
        return path.read_bytes()
    except FileNotFoundError:
        pass
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(secrets.token_bytes(32))
    try:
        os.link(tmp, path)  # the first process to make one wins
    except FileExistsError:
        pass
    finally:
        tmp.unlink(missing_ok=True)
    return path.read_bytes()


def _sign(key: bytes, name: str, expires: int, token_hash: str) -> str:
    msg = f"{name}|{expires}|{token_hash}".encode()
    return hmac.new(key, msg, hashlib.sha256).hexdigest()


def make_session(settings: Settings, users: dict[str, User], token: str) -> str | None:
    """A session value for the user of ``token`` (None if no user has it):
    ``name.expires.signature``, signed with the service's key and the token's hash, so
    that changing or removing the user's token ends their sessions."""
    user = find_user(users, token)
    if user is None:
        return None
    expires = int(time.time()) + SESSION_S
    sig = _sign(_session_key(settings), user.name, expires, hash_token(token))
    return f"{base64.urlsafe_b64encode(user.name.encode()).decode()}.{expires}.{sig}"


def session_user(request: Request, users: dict[str, User]) -> User | None:
    """The user of the jobs page's session cookie, for reading requests (GET, HEAD)."""
    if request.method not in ("GET", "HEAD"):
        return None
    return check_session(request.app.state.settings, users, request.cookies.get(SESSION_COOKIE))


def check_session(settings: Settings, users: dict[str, User], value: str | None) -> User | None:
    """The user a session value names, if its signature holds, it has not expired and the
    user still has the token it was made with."""
    if not value or value.count(".") != 2:
        return None
    b64, expires_s, sig = value.split(".")
    try:
        name = base64.urlsafe_b64decode(b64.encode()).decode()
        expires = int(expires_s)
    except (ValueError, UnicodeDecodeError):
        return None
    if expires < time.time():
        return None
    key = _session_key(settings)
    found = None
    for digest, user in users.items():
        if user.name == name and hmac.compare_digest(_sign(key, name, expires, digest), sig):
            found = user
    return found


def require_admin(request: Request) -> User:
    """Like :func:`require_token`, and the user must be an admin (401 otherwise)."""
    user = require_token(request)
    if user.role != "admin":
        raise ServiceProblem(
            "unauthorized",
            f"{user.name} is not an admin: this needs an admin's token",
            headers={"WWW-Authenticate": 'Bearer realm="treesim"'},
        )
    return user


UserDep = Annotated[User, Depends(require_token)]


def metrics_access(request: Request) -> None:
    """``/metrics`` is for an admin while a token is set, unless ``TREESIM_METRICS_OPEN``
    opens it (a Prometheus that cannot send a token)."""
    if not request.app.state.settings.metrics_open:
        require_admin(request)
