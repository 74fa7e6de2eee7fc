"""The viewer's access token, kept across restarts of the viewer of one fleet.

A restarted viewer with a new token answered 403 to every tab still open on it (the demo
restarts a viewer that died). So the token lives in ``<state dir>/<fleet>/viewer.token``
(``fleet.state_dir``: the agents' state directory; the demo gives each run its own), created with
mode 0600 and written whole (a temporary file linked into place: two viewers starting at once
both end up with the one that got there first). A file that others could read, that is not
ours or not a regular file, or that holds no usable token is replaced by a new token (the
old one may have leaked). Where no file can be written the viewer makes a token per run, as
before, and says so. The token itself is never logged.
"""

from __future__ import annotations

import logging
import os
import stat
from pathlib import Path

from fleet.state_dir import default_state_dir
from fleet.web.access import check_token, new_token

log = logging.getLogger("fleet.web.token_store")

TOKEN_FILE = "viewer.token"
MAX_TOKEN_BYTES = 256
"""A token is at most 128 characters; anything much longer is not one."""


def token_path(fleet: str, directory: Path | None = None) -> Path:
    """Where the viewer of ``fleet`` keeps its token."""
    return (directory or default_state_dir()) / fleet / TOKEN_FILE


class UnusableTokenFile(Exception):
    """The token file exists but must not be used; the message says why (never the token)."""


def _read(path: Path) -> str | None:
    """The token in ``path``; None when there is no file; UnusableTokenFile otherwise."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as exc:  # a symbolic link (ELOOP), no permission...
        raise UnusableTokenFile(f"cannot be opened ({exc.strerror})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise UnusableTokenFile("is not a regular file")
        if info.st_uid != os.getuid():
            raise UnusableTokenFile("belongs to another user")
        if info.st_mode & 0o077:
            raise UnusableTokenFile(f"was readable by others (mode {info.st_mode & 0o777:o})")
        data = os.read(fd, MAX_TOKEN_BYTES + 1)
    finally:
        os.close(fd)
    try:
        return check_token(data.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        raise UnusableTokenFile("holds no usable token") from None


def _create(path: Path) -> str:
    """A new token written to ``path`` (mode 0600), or the one another viewer wrote first."""
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    token = new_token()
    temporary = path.with_name(f".{TOKEN_FILE}.{os.getpid()}")
    fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o600)
    try:
        os.write(fd, f"{token}\n".encode())
        os.fsync(fd)
    finally:
        os.close(fd)
    try:
        os.link(temporary, path)  # fails if another viewer got there first: use its token
    except FileExistsError:
        token = _read(path) or token
    finally:
        temporary.unlink(missing_ok=True)
    return token


def viewer_token(fleet: str, directory: Path | None = None, renew: bool = False) -> str:
    """The kept token of the viewer of ``fleet`` (made and kept on first use); ``renew``:
    replace it with a new one (every open tab then needs the new URL)."""
    path = token_path(fleet, directory)
    try:
        if renew:
            path.unlink(missing_ok=True)
        try:
            token = _read(path)
        except UnusableTokenFile as why:
            log.warning("%s %s: replaced by a new token", path, why)
            path.unlink(missing_ok=True)
            token = None
        if token is None:
            token = _create(path)
            log.info("the viewer's token is kept in %s (mode 0600)", path)
        return token
    except (OSError, UnusableTokenFile) as exc:
        log.warning(
            "cannot keep the viewer's token in %s (%s): a new token for this run only",
            path,
            getattr(exc, "strerror", None) or exc,
        )
        return new_token()
