"""The key a client address is counted under (the per-address connection cap, the failed-key limiter)."""

from __future__ import annotations

import ipaddress


def address_key(host: str) -> str:
    """The key the per-address cap counts under: the address itself, an IPv6 one by its /64 (one host
    usually holds a whole /64), an IPv4-mapped IPv6 one as the IPv4 address."""
    if ":" not in host:
        return host
    try:
        address = ipaddress.IPv6Address(host.split("%", 1)[0])
    except ValueError:
        return host
    if address.ipv4_mapped is not None:
        return str(address.ipv4_mapped)
    return str(ipaddress.IPv6Network((address, 64), strict=False))
