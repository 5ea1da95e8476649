"""The ``pmht-opt`` command: a thin layer over the library.

Every subcommand turns its options into library calls: ``plan`` loads a mission file
(:func:`pmht_opt.io.load_mission`), overrides its planner settings with the options given, and runs it
with :func:`pmht_opt.io.plan_mission`; ``order`` runs :func:`pmht_opt.io.order_mission`. Outputs are
checked (format, directory, writable) before anything is planned.

The parts: :mod:`~pmht_opt.cli.parser` (the options), :mod:`~pmht_opt.cli.settings` (options onto a
mission's settings), :mod:`~pmht_opt.cli.outputs` (checking and writing files),
:mod:`~pmht_opt.cli.commands` (the subcommands); this module runs them and turns what they raise into
one line and an exit status.

Exit status: 0 done; 2 a bad input or a failed solve (``pmht-opt: error: ...``, one line, never a
traceback); 130 interrupted (Ctrl-C); 141 the reader of the output went away (``pmht-opt ... | head``),
as for a process ended by SIGPIPE.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import warnings
from collections.abc import Iterator, Sequence
from typing import Any

from pmht_opt.cli import commands
from pmht_opt.cli.parser import build_parser
from pmht_opt.exceptions import PmhtOptError

#: Exit statuses.
EXIT_ERROR, EXIT_INTERRUPTED, EXIT_PIPE = 2, 130, 141

#: The library's words in its messages, and what a user of the command line writes instead: a flag,
#: or a key of the mission file.
CLI_WORDS: tuple[tuple[str, str], ...] = (
    (r"solver='(\w+)' or '(\w+)'", r"--solver \1 or --solver \2"),
    (r"solver='(\w+)'", r"--solver \1"),
    (
        r"solver_settings=\{'mstep_work_limit': None\}",
        "a larger mstep_work_limit in the mission's [planner] solver_settings",
    ),
    (r"pass accept_inaccurate=True", "set accept_inaccurate = true in the mission's [planner]"),
    (r"soft=True", "soft = true in the constraint's table"),
    (r"give the radius instead", "give --radius instead"),
    (r"pass radius=", "give --radius"),
)


def cli_words(message: str) -> str:
    """``message`` with the library's words replaced by the command line's (:data:`CLI_WORDS`)."""
    for pattern, replacement in CLI_WORDS:
        message = re.sub(pattern, replacement, message)
    return message


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's last flush finds no closed pipe."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


@contextlib.contextmanager
def one_line_warnings() -> Iterator[None]:
    """Show every warning raised within as one line on stderr, ``pmht-opt: warning: MESSAGE``, in the
    command line's words: a user of the command sees neither Python's warning format nor a source
    line of the library."""
    with warnings.catch_warnings():
        warnings.simplefilter("default")

        def show(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
            print(f"pmht-opt: warning: {cli_words(str(message))}", file=sys.stderr)

        warnings.showwarning = show
        yield


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (module notes)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv[:1] == ["study"]:
            return commands.study(argv[1:])
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as exc:  # --help, --version, or argparse's own usage error (status 2)
            return exc.code if isinstance(exc.code, int) else EXIT_ERROR
        with one_line_warnings():
            code: int = args.func(args)
        sys.stdout.flush()
    except PmhtOptError as err:
        print(f"pmht-opt: error: {cli_words(str(err))}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("pmht-opt: interrupted.", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_PIPE
    except OSError as err:  # a file that vanished or a full disk between the checks and the writing
        name = f" {err.filename!r}" if err.filename else ""
        print(f"pmht-opt: error: cannot write{name}: {err.strerror or err}.", file=sys.stderr)
        return EXIT_ERROR
    return code
