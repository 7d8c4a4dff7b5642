"""The ``bimscan`` command group: every command, registered from one module per area
(``cli/ifc_commands.py``, ...). Importing it loads NumPy, SciPy and Numba (the settings the
commands' options declare), a second or more on a busy machine: the entry point
(``bimscan.cli.main``) imports it after its signal handlers are in place."""

from __future__ import annotations

import click

from bimscan import __version__
from bimscan.cli import (
    compare_commands, dataset_commands, generate_commands, ifc_commands, learn_commands, plan_commands, scan_commands,
)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="bimscan")
def cli() -> None:
    """Labelled synthetic laser scans from BIM (IFC) models: tripod (TLS), mobile (handheld,
    backpack) and flying (drone), on the site as it stands, at dataset scale.

    \b
    IFC -> labelled components -> site as scanned -> planned survey (stations, a walk or a flight)
        -> virtual scanner -> labelled clouds -> datasets (local or on Ray) -> statistics
        -> segmentation: train, evaluate on real scans, adapt to your own, predict.
    A site scan against its model: align it, then say per element what is built (progress).

    Start with `bimscan demo OUT` (the whole pipeline on two generated buildings, in minutes);
    `bimscan COMMAND --help` says what each command takes.
    """


for _module in (ifc_commands, generate_commands, scan_commands, plan_commands, compare_commands, dataset_commands,
                learn_commands):
    for _command in _module.COMMANDS:
        cli.add_command(_command)
