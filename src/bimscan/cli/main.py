"""Entry point of the ``bimscan`` console script.

Commands live in one module per area (``cli/ifc_commands.py``, ...), registered in the command
group (``cli/commands.py``). User errors (``BimscanError``) become one line on stderr and a
non-zero exit, never a traceback. Heavy libraries (Open3D, torch, Ray) are imported inside
commands so ``--help`` stays fast.

Signals: SIGINT (Ctrl-C) and SIGTERM stop a command the same way, by an exception raised in the
main thread, so every ``finally`` runs (temporary outputs are removed) before the one line
``error: interrupted`` (exit 130) or ``error: terminated`` (exit 143). This module imports the
standard library only (and ``bimscan.processes``), so the handlers are in place a few hundredths of
a second after the interpreter starts: the
command group, whose options load NumPy, SciPy and Numba (a second or more on a busy machine),
is imported by ``main`` after them, and a stop there ends the same way. A Ctrl-C that lands while
a library is being imported (Open3D turns it into an ImportError) gives the same one line, and so
does an error that a library made of the signal. Handlers are held while lazrs runs
(``bimscan.processes.signals_held``), whose callbacks would swallow the exception. Python
warnings and log records of the libraries print as ``warning: ...`` lines; the resource tracker,
which removes a killed command's semaphores, does so without its raw warning
(``bimscan.processes.quiet_resource_tracker``).
"""

from __future__ import annotations

import signal
import sys
import threading
import time
import warnings
from types import FrameType
from typing import TYPE_CHECKING

from bimscan.processes import quiet_resource_tracker

if TYPE_CHECKING:
    import logging


def _echo(line: str) -> None:
    """One line on stderr, whatever it holds (file names that are not valid UTF-8 reach Python as
    surrogate escapes, which a terminal cannot print)."""
    if sys.stderr is not None:  # (None: a process started without one)
        sys.stderr.write(line.encode("utf-8", "backslashreplace").decode("utf-8") + "\n")
        sys.stderr.flush()


def _error(message: str) -> None:
    """Print ``error: <message>`` on stderr as one line."""
    _echo(f"error: {' '.join(message.split())}")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C's KeyboardInterrupt so that the same clean-up runs."""


# The signal that stops this run (signal number), and when it was last raised as an exception.
_STOPPING: dict[str, float] = {"signal": 0, "raised_at": 0.0}
_REPEAT_GRACE_S = 2.0  # a second Ctrl-C this soon after the first does not cut the clean-up short


def _on_signal(number: int, frame: FrameType | None) -> None:
    del frame
    first = not _STOPPING["signal"]
    _STOPPING["signal"] = _STOPPING["signal"] or number
    now = time.monotonic()
    if not first and now - _STOPPING["raised_at"] < _REPEAT_GRACE_S:
        return
    _STOPPING["raised_at"] = now
    raise Terminated() if number == signal.SIGTERM else KeyboardInterrupt()


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: object = None, line: str | None = None) -> None:
    del category, filename, lineno, file, line
    _echo(f"warning: {' '.join(str(message).split())}")


def _warning_lines() -> logging.Handler:
    """A log handler that prints library log records (laspy, Ray, ...) as ``warning: ...`` lines."""
    import logging  # (a few hundredths of a second: after the signal handlers are in place)

    class WarningLines(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            _echo(f"warning: {' '.join(record.getMessage().split())}")

    return WarningLines(logging.WARNING)


# What a stopped command leaves, by command: those that keep finished work and resume from it,
# and training, which continues from its last checkpoint with --resume; the others leave nothing
# (their outputs are written under temporary names and removed).
RESUMES = {"build": "run the same command to resume", "sim2real": "run the same command to resume",
           "demo": "run the same command to resume", "adapt": "run the same command to resume",
           "train": "add --resume to continue from the last epoch"}


def _stopped(command: str | None = None) -> int:
    """Print the one line for a stopped run of ``command``; its exit status (130 Ctrl-C, 143 SIGTERM)."""
    what = "terminated" if _STOPPING["signal"] == signal.SIGTERM else "interrupted"
    then = (f"finished work is kept, {RESUMES[command]}" if command in RESUMES
            else "no partial output was left behind")
    _echo(f"error: {what}; {then}")
    return 128 + signal.SIGTERM if _STOPPING["signal"] == signal.SIGTERM else 130


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status."""
    _STOPPING.update(signal=0, raised_at=0.0)
    quiet_resource_tracker()
    previous = {}
    if threading.current_thread() is threading.main_thread():  # only the main thread may set handlers
        previous = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}
        for number in previous:
            signal.signal(number, _on_signal)
    import logging

    root = logging.getLogger()
    lines = _warning_lines() if not root.handlers else None  # keep a caller's own logging set-up
    if lines is not None:
        root.addHandler(lines)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return _run(argv)
    finally:
        if lines is not None:
            root.removeHandler(lines)
        for number, handler in previous.items():
            signal.signal(number, handler)


def _run(argv: list[str] | None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    try:  # the commands and the libraries their options need: a stop while they load stopped nothing yet
        from bimscan.cli.commands import cli
    except Exception:
        if _STOPPING["signal"]:  # a library that turned the signal into its own error
            return _stopped()
        raise
    except KeyboardInterrupt:
        return _stopped()
    import errno

    import click

    from bimscan.errors import BimscanError

    command = next((a for a in args if not a.startswith("-")), None)  # the subcommand (the group takes no values)
    try:
        # click's own main() would print a blank line on Ctrl-C: the context is made and invoked here.
        with cli.make_context("bimscan", args) as context:
            status = cli.invoke(context)
    except click.exceptions.Exit as exc:  # --help, --version
        return exc.exit_code
    except click.exceptions.Abort:
        return _stopped(command)
    except click.UsageError as exc:  # a bad option or argument: one line, like every other error
        command = f"bimscan {exc.ctx.command_path.split(' ', 1)[1]} " if exc.ctx and " " in exc.ctx.command_path else "bimscan "
        _error(f"{exc.format_message()} (see '{command}--help')")
        return exc.exit_code
    except click.ClickException as exc:
        _error(exc.format_message())
        return exc.exit_code
    except BimscanError as exc:
        if _STOPPING["signal"]:  # an error the stop caused (a library that turned the signal into its own error)
            return _stopped(command)
        _error(str(exc))
        return exc.exit_code
    except KeyboardInterrupt:
        return _stopped(command)
    except OSError as exc:
        if _STOPPING["signal"]:
            return _stopped(command)
        if exc.errno == errno.ENOSPC:
            _error(f"disk full while writing {exc.filename or 'output'}; free space and run again")
        else:
            _error(f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": "))
        return 1
    except Exception:
        if _STOPPING["signal"]:  # e.g. Open3D's "initialization failed" ImportError after a Ctrl-C in its import
            return _stopped(command)
        raise
    return status if isinstance(status, int) else 0


if __name__ == "__main__":
    sys.exit(main())
