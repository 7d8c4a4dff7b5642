"""Seeded mutations of IFC-SPF text, the kind real files and bad copies suffer (for the fuzz tests)."""

from __future__ import annotations

import re

import numpy as np

_REF = re.compile(rb"#[0-9]+")
_ATTRIBUTE = re.compile(rb"(?<=[(,])(?:'[^']*'|[^,()']*)(?=[,)])")
_ENTITY = re.compile(rb"=\s*(IFC[A-Z0-9_]+)\(")
END = b"\nENDSEC;\nEND-ISO-10303-21;\n"


def _data_lines(data: bytes) -> list[tuple[int, int]]:
    """(start, end) of the lines of the DATA section that define an instance."""
    return [(m.start(), m.end()) for m in re.finditer(rb"(?m)^#[0-9]+=.*$", data)]


def truncate(data: bytes, rng: np.random.Generator) -> bytes:
    """Cut the file somewhere in its second half, with (usually) a valid end appended."""
    cut = int(rng.integers(len(data) // 2, len(data) - 30))
    return data[:cut] + (END if rng.random() < 0.8 else b"")


def flip_bits(data: bytes, rng: np.random.Generator) -> bytes:
    out = bytearray(data)
    start = data.find(b"DATA;")
    for _ in range(int(rng.integers(1, 6))):
        position = int(rng.integers(start, len(out) - 30))
        out[position] ^= 1 << int(rng.integers(0, 8))
    return bytes(out)


def delete_lines(data: bytes, rng: np.random.Generator) -> bytes:
    lines = _data_lines(data)
    for _ in range(int(rng.integers(1, 4))):
        start, end = lines[int(rng.integers(len(lines)))]
        data = data[:start] + b" " * (end - start) + data[end:]  # offsets of the other lines kept
    return data


def star_or_dollar(data: bytes, rng: np.random.Generator) -> bytes:
    """Replace a few whole attributes by '*' or '$' (derived, unset), as some exporters do."""
    lines = _data_lines(data)
    out = data
    for _ in range(int(rng.integers(1, 6))):
        start, end = lines[int(rng.integers(len(lines)))]
        line = out[start:end]
        spans = [m.span() for m in _ATTRIBUTE.finditer(line)]
        if not spans:
            continue
        a, b = spans[int(rng.integers(len(spans)))]
        token = b"*" if rng.random() < 0.5 else b"$"
        line = line[:a] + token + line[b:]
        out = out[:start] + line.ljust(end - start) + out[end:]
        lines = _data_lines(out)
    return out


def dangling(data: bytes, rng: np.random.Generator) -> bytes:
    refs = list(_REF.finditer(data, data.find(b"DATA;")))
    refs = [m for m in refs if data[m.end():m.end() + 1] != b"="]
    for _ in range(int(rng.integers(1, 4))):
        match = refs[int(rng.integers(len(refs)))]
        data = data[:match.start()] + b"#9" + data[match.start() + 2:match.end()] + data[match.end():] \
            if match.end() - match.start() > 2 else data
    return data


def unknown_entity(data: bytes, rng: np.random.Generator) -> bytes:
    names = list(_ENTITY.finditer(data))
    match = names[int(rng.integers(len(names)))]
    return data[:match.end(1)] + b"X" + data[match.end(1):]


def garble(data: bytes, rng: np.random.Generator) -> bytes:
    """Unbalanced brackets, a stray quote or junk in one line."""
    lines = _data_lines(data)
    start, end = lines[int(rng.integers(len(lines)))]
    position = int(rng.integers(start + 3, end))
    junk = [b"((", b")", b"'", b";;", b",,", b"\x00\xff", b"=#"][int(rng.integers(7))]
    return data[:position] + junk + data[position:]


def unit_edit(data: bytes, rng: np.random.Generator) -> bytes:
    """Lose or change the length unit: unassign, dangle or drop it, or change its prefix."""
    choice = int(rng.integers(4))
    match = re.search(rb"(#[0-9]+)\s*=\s*IFCSIUNIT\(\*,\.LENGTHUNIT\.,([^,]*),\.METRE\.\)", data)
    if match is None:
        return data
    if choice == 0:  # drop the unit from the assignment
        return re.sub(rb"IFCUNITASSIGNMENT\(\((.*?)\)\)",
                      lambda m: b"IFCUNITASSIGNMENT((" + b",".join(
                          r for r in m.group(1).split(b",") if r.strip() != match.group(1)) + b"))", data, count=1)
    if choice == 1:  # dangle it
        return data[:match.start()] + b"#987654=" + data[match.start() + len(match.group(1)) + 1:]
    if choice == 2:  # delete its line
        return data[:match.start()] + b" " * (match.end() - match.start() + 1) + data[match.end() + 1:]
    prefix = [b"$", b".MILLI.", b".CENTI.", b".KILO."][int(rng.integers(4))]
    return data[:match.start(2)] + prefix + data[match.end(2):]


MUTATIONS = {
    "truncate": truncate, "flip_bits": flip_bits, "delete_lines": delete_lines, "star_or_dollar": star_or_dollar,
    "dangling": dangling, "unknown_entity": unknown_entity, "garble": garble, "unit_edit": unit_edit,
}


def mutate(data: bytes, seed: int) -> tuple[str, bytes]:
    """One seeded mutant of ``data``: (mutation name, bytes)."""
    rng = np.random.default_rng(seed)
    names = sorted(MUTATIONS)
    name = names[seed % len(names)]
    return name, MUTATIONS[name](data, rng)
