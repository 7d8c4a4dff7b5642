"""IFC GlobalIds that bimscan makes itself (for instances a file left without one, and for the
objects site dressing adds): valid, stable, and the same on every machine."""

from __future__ import annotations

import uuid

IFC_BASE64 = "0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_$"
_NAMESPACE = uuid.UUID("0b5d3c52-3f6e-4c55-9a7e-6a2b1f0c9d41")


def is_global_id(text: object) -> bool:
    """Whether ``text`` is an IFC GlobalId: 22 characters of IFC's base 64, the first 0-3 (the 128
    bits of a GUID leave the first character 2 bits)."""
    return (isinstance(text, str) and len(text) == 22 and text[0] in "0123"
            and all(c in IFC_BASE64 for c in text))


def derived_global_id(*parts: object) -> str:
    """The GlobalId of a name-based UUID (RFC 4122 version 5) of ``parts`` joined by ':', in IFC's
    22-character base 64 (its first character 0-3, as IFC requires)."""
    number = uuid.uuid5(_NAMESPACE, ":".join(map(str, parts))).int
    digits = []
    for _ in range(22):
        digits.append(IFC_BASE64[number & 63])
        number >>= 6
    return "".join(reversed(digits))
