"""Network addresses as every command writes them: ``HOST:PORT``, IPv6 in brackets.

One parser for every option that takes an address (``--server``, ``--live``, ``--target``,
``--listen``) and one loopback test for every bind-address warning.
"""

from __future__ import annotations

import ipaddress

from kinefuse.errors import InputError

__all__ = ["is_loopback", "parse_hostport"]


def is_loopback(host: str) -> bool:
    """True for a loopback address (127.0.0.0/8, ::1) and ``localhost``."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def parse_hostport(text: str, default_port: int | None = 7400) -> tuple[str, int]:
    """``HOST:PORT`` (or ``HOST`` when ``default_port`` is given) -> ``(host, port)``.

    An IPv6 address goes in brackets, ``[::1]:7400`` or ``[::1]``; a bare one is refused, since
    ``::1:7400`` is both an address and an address with a port.

    Raises
    ------
    InputError
        Naming the text and the expected form.
    """
    form = "expected HOST:PORT, e.g. 127.0.0.1:7400 (IPv6 as [::1]:7400)"
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise InputError(f"bad address {text!r}: no closing ']'; {form}")
        host, rest = text[1:end], text[end + 1 :]
        if rest and not rest.startswith(":"):
            raise InputError(f"bad address {text!r}: {form}")
        port_text = rest[1:] if rest else None
    elif text.count(":") > 1:
        raise InputError(f"bad address {text!r}: an IPv6 address needs brackets; {form}")
    else:
        host, sep, port_text_ = text.partition(":")
        port_text = port_text_ if sep else None
    if not host:
        raise InputError(f"bad address {text!r}: no host; {form}")
    if port_text is None:
        if default_port is None:
            raise InputError(f"bad address {text!r}: no port; {form}")
        return host, default_port
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise InputError(f"bad port in {text!r}: expected a number 0-65535")
    return host, int(port_text)
