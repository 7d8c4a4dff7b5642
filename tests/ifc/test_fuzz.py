"""Fuzzing the IFC loader: a few hundred seeded mutations of small IFC files (truncation, bit flips,
deleted lines, '*'/'$' attributes, dangling references, unknown entities, garbled lines, unit
edits). For every mutant: no traceback, no hang, a loaded model only with every declared element
loaded or reported, an error only as one line (issue 13)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from bimscan.errors import BimscanError
from bimscan.ifc.load import load_ifc

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


N_PER_BASE = 120  # mutants per base file; 3 bases
CASE_LIMIT_S = 60.0  # no mutant may take longer (the watchdog's limit per element is 3 s here)
ELEMENTS = re.compile(rb"(?m)^#([0-9]+)=(IFC(?:WALL|SLAB|COLUMN|DOOR)\(.*)$")


@pytest.fixture
def bases(box_room_ifc: Path, tiny_model, tmp_path: Path) -> list[Path]:
    """Small models of all three schemas, with walls, slabs, a column and a door."""
    old = tiny_model("IFC2X3")
    old.add_box("IfcSlab", origin=(0.0, 0.0, -0.2), size=(5.0, 4.0, 0.2), predefined_type="FLOOR")
    old.add_box("IfcWall", size=(5.0, 0.2, 3.0))
    old.add_box("IfcWall", origin=(0.0, 3.8, 0.0), size=(5.0, 0.2, 3.0))
    new = tiny_model("IFC4X3")
    new.add_box("IfcWall", size=(4.0, 0.2, 3.0))
    new.add_box("IfcColumn", origin=(2.0, 2.0, 0.0), size=(0.3, 0.3, 3.0))
    new.add_box("IfcDoor", origin=(1.0, 0.0, 0.0), size=(0.9, 0.2, 2.1))
    return [box_room_ifc, old.write(tmp_path / "old2x3.ifc"), new.write(tmp_path / "new4x3.ifc")]


def _declared(data: bytes, original: dict[int, bytes]) -> set[int]:
    """Elements of the base file whose defining line the mutant still holds unchanged."""
    return {step_id for step_id, line in original.items() if re.search(rb"(?m)^" + re.escape(line) + rb"$", data)}


@pytest.mark.slow
def test_mutated_ifc_files_load_with_every_loss_reported_or_fail_in_one_line(bases, tmp_path):
    outcomes: Counter[tuple[str, str]] = Counter()
    slowest = 0.0
    for base in bases:
        data = base.read_bytes()
        original = {int(m.group(1)): m.group(0) for m in ELEMENTS.finditer(data)}
        assert len(load_ifc(base).components) == len(original)
        for seed in range(N_PER_BASE):
            name, mutant = mutate(data, seed)
            path = tmp_path / f"{base.stem}-{seed}.ifc"
            path.write_bytes(mutant)
            start = time.perf_counter()
            try:
                model = load_ifc(path, use_cache=False, element_timeout_s=3.0, progress=False)
            except BimscanError as exc:
                message = str(exc)
                assert "\n" not in message and "internal error" not in message, (path, message)
                outcomes[(name, "error")] += 1
                continue
            finally:
                slowest = max(slowest, time.perf_counter() - start)
                assert time.perf_counter() - start < CASE_LIMIT_S, path
            accounted = set(model.components.step_id.tolist()) | {f.step_id for f in model.failed}
            missing = _declared(mutant, original) - accounted
            assert not missing, (path, name, sorted(missing))
            outcomes[(name, "loaded")] += 1
    total = sum(outcomes.values())
    assert total == N_PER_BASE * len(bases)
    loaded = sum(n for (_, result), n in outcomes.items() if result == "loaded")
    assert loaded > total // 2, outcomes  # most damage is survivable: the fuzz must exercise loading
    print(f"\nfuzz: {total} mutants, {loaded} loaded (every declared element loaded or reported), "
          f"{total - loaded} one-line errors; slowest {slowest:.1f} s; by mutation: "
          + json.dumps({f"{k[0]}/{k[1]}": v for k, v in sorted(outcomes.items())}))


@pytest.mark.slow
def test_the_cli_on_mutants_exits_0_with_warnings_or_1_with_one_error_line(bases, capsys, monkeypatch):
    from bimscan.cli.main import main

    monkeypatch.setenv("BIMSCAN_ELEMENT_TIMEOUT_S", "3")
    data = bases[0].read_bytes()
    seen = set()
    for seed in range(len(MUTATIONS)):  # one mutant of every kind
        name, mutant = mutate(data, seed)
        path = bases[0].with_name(f"cli-{seed}.ifc")
        path.write_bytes(mutant)
        status = main(["info", str(path), "--json", "--no-cache"])
        out, err = capsys.readouterr()
        lines = err.splitlines()
        if status == 0:
            summary = json.loads(out)
            assert all(line.startswith("warning: ") for line in lines), err
            assert summary["components"] + len(summary["failed"]) == summary["declared_elements"]
        else:
            assert status == 1 and len(lines) == 1 and lines[0].startswith("error: "), err
        seen.add(name)
    assert seen == set(MUTATIONS)


def test_the_console_script_on_a_garbled_file_warns_with_the_line_and_refuses_it_under_strict(bases, tmp_path):
    data = bases[0].read_bytes()
    wall = re.search(rb"(?m)^#[0-9]+=IFCWALL\(", data)
    line = data.count(b"\n", 0, wall.start()) + 1
    path = tmp_path / "garbled.ifc"
    path.write_bytes(data[:wall.end()] + b"((" + data[wall.end():])
    env = {**os.environ, "BIMSCAN_PROGRESS": "0"}
    command = [sys.executable, "-c", "import sys; from bimscan.cli.main import main; sys.exit(main())", "info", str(path)]
    run = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr and f"(line {line})" in run.stderr
    assert all(text.startswith("warning: ") for text in run.stderr.splitlines())
    strict = subprocess.run([*command, "--strict"], capture_output=True, text=True, env=env, timeout=300)
    assert strict.returncode == 1 and strict.stderr.count("\n") == 1
    assert strict.stderr.startswith("error: ") and f"line {line}" in strict.stderr
