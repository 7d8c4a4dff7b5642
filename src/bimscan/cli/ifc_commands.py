"""IFC commands: info, export-obj, make-building."""

from __future__ import annotations

import click

COMMANDS: list[click.Command] = []
