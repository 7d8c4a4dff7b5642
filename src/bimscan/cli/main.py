"""Entry point of the ``bimscan`` console script.

Commands live in one module per area (``cli/ifc_commands.py``, ...) and are registered here.
User errors (``BimscanError``) become one line on stderr and a non-zero exit, never a traceback.
Heavy libraries (Open3D, torch, Ray) are imported inside commands so ``--help`` stays fast.
"""

from __future__ import annotations

import errno
import sys

import click

from bimscan import __version__
from bimscan.errors import BimscanError


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="bimscan")
def cli() -> None:
    """Labelled synthetic terrestrial laser scans from BIM (IFC) models.

    IFC -> components -> semantic classes -> virtual TLS -> labelled clouds -> datasets ->
    statistics -> segmentation baseline.
    """


def _register() -> None:
    from bimscan.cli import dataset_commands, generate_commands, ifc_commands, learn_commands, scan_commands

    for module in (ifc_commands, generate_commands, scan_commands, dataset_commands, learn_commands):
        for command in module.COMMANDS:
            cli.add_command(command)


_register()


def _error(message: str) -> None:
    """Print ``error: <message>`` on stderr as one line, whatever the message holds (file names that
    are not valid UTF-8 reach Python as surrogate escapes, which a terminal cannot print)."""
    line = " ".join(message.split()).encode("utf-8", "backslashreplace").decode("utf-8")
    click.echo(f"error: {line}", err=True)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status."""
    try:
        status = cli.main(args=argv, prog_name="bimscan", standalone_mode=False)
    except click.exceptions.Abort:
        _error("interrupted")
        return 130
    except click.UsageError as exc:  # a bad option or argument: one line, like every other error
        command = f"bimscan {exc.ctx.command_path.split(' ', 1)[1]} " if exc.ctx and " " in exc.ctx.command_path else "bimscan "
        _error(f"{exc.format_message()} (see '{command}--help')")
        return exc.exit_code
    except click.ClickException as exc:
        _error(exc.format_message())
        return exc.exit_code
    except BimscanError as exc:
        _error(str(exc))
        return exc.exit_code
    except KeyboardInterrupt:
        _error("interrupted; finished work is kept, run the same command to resume")
        return 130
    except OSError as exc:
        if exc.errno == errno.ENOSPC:
            _error(f"disk full while writing {exc.filename or 'output'}; free space and run again")
        else:
            _error(f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": "))
        return 1
    return status if isinstance(status, int) else 0


if __name__ == "__main__":
    sys.exit(main())
