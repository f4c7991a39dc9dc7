"""``[HOST:]PORT`` of the live view's local web server."""

from __future__ import annotations

import ipaddress

from pmalab.errors import ConfigError

#: the only interface served unless the user names another
DEFAULT_HOST = "127.0.0.1"


def parse_address(text: str, option: str = "--live") -> tuple[str, int]:
    """``"8765"`` → ``("127.0.0.1", 8765)``; ``"0.0.0.0:8765"``, ``"[::1]:8765"``,
    ``"localhost:0"`` (port 0: any free port).  Raises :class:`ConfigError` (one line)."""
    raw = text.strip()
    host, sep, port_text = raw.rpartition(":")
    if not sep:
        host, port_text = DEFAULT_HOST, raw
    elif host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif not host or ":" in host:  # ":8765" or a bare IPv6 address without brackets
        raise ConfigError(f"{option}: expected [HOST:]PORT (IPv6 as [ADDR]:PORT), got {text!r}")
    try:
        port = int(port_text)
    except ValueError:
        raise ConfigError(f"{option}: port must be an integer 0–65535, got {port_text!r}") from None
    if not 0 <= port <= 65535:
        raise ConfigError(f"{option}: port must be an integer 0–65535, got {port}")
    return host, port


def is_loopback(addr: str) -> bool:
    """True for a client address on this machine (127.0.0.0/8, ::1, ::ffff:127.x)."""
    try:
        ip = ipaddress.ip_address(addr.split("%", 1)[0])
    except ValueError:
        return False
    mapped = getattr(ip, "ipv4_mapped", None)
    return bool(ip.is_loopback or (mapped is not None and mapped.is_loopback))


def url_host(host: str) -> str:
    """The host as written in a URL (IPv6 in brackets; the wildcard as 127.0.0.1)."""
    if host in ("", "0.0.0.0"):
        return DEFAULT_HOST
    if host == "::":
        return "[::1]"
    return f"[{host}]" if ":" in host else host
