"""The ``borescan`` console command: dispatches to :mod:`borescan.commands` modules.

User errors end with a one-line message on stderr and exit code 2 (exit 1 where a command's
answer is "no", see :mod:`borescan.commands._common`), never with a traceback; a closed output
pipe (``borescan sql ... | head``) ends the command quietly with the shell's SIGPIPE status 141.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from borescan import __version__, commands
from borescan.commands._common import CommandFailed, UsageError

#: exit status of a command whose output pipe was closed (128 + SIGPIPE, as the shell reports it)
EXIT_BROKEN_PIPE = 141

#: exceptions that mean the user asked for something impossible (a file that is not there, a
#: scan that exists already, ...), reported by their message; anything else is a bug and keeps
#: its traceback
_USER_ERRORS: tuple[type[BaseException], ...] = (
    FileNotFoundError,
    FileExistsError,
    NotADirectoryError,
    IsADirectoryError,
    PermissionError,
)


def _module_names() -> list[str]:
    """Return the command modules of :mod:`borescan.commands`, by name, without importing them."""
    return sorted(i.name for i in pkgutil.iter_modules(commands.__path__) if not i.name.startswith("_"))


def _command_modules(names: list[str] | None = None) -> list:
    return [importlib.import_module(f"borescan.commands.{n}") for n in (names or _module_names())]


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """Return the ``borescan`` parser.

    Return the ``borescan`` parser. With ``only`` (a command module's name) only that command is
    imported and added, so a command never pays for what the others import.
    """
    parser = argparse.ArgumentParser(
        prog="borescan",
        description="Bore scans from laser displacement sensors: simulate, import, validate, trace, "
        "query, status.",
        epilog="Exit codes: 0 done; 1 the answer is no (problems found, unknown id, query failed); "
        "2 cannot run as asked (bad arguments, missing files).",
    )
    parser.add_argument("--version", action="version", version=f"borescan {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _command_modules([only] if only else None):
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _command_in(argv: list[str]) -> str | None:
    """Return the module of the subcommand ``argv`` names, if any.

    Return the module of the subcommand ``argv`` names (its first word that is not an option; module
    names are command names with '_' for '-'), if there is one.
    """
    first = next((a for a in argv if not a.startswith("-")), None)
    if first is None or first.replace("-", "_") not in _module_names():
        return None
    mod = importlib.import_module(f"borescan.commands.{first.replace('-', '_')}")
    return mod.__name__.rpartition(".")[2] if mod.NAME == first else None


def _scan_error() -> type[BaseException]:
    from borescan.rawio import ScanError  # a scan id or night the raw format refuses (simulate, import)

    return ScanError


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # stdout without a file descriptor (captured): nothing to flush
        pass


def main(argv: list[str] | None = None) -> int:
    """Run the ``borescan`` command line with ``argv``; return the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(only=_command_in(argv))
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    name = f"borescan {args.command}"
    try:
        code = int(args._run(args) or 0)
        sys.stdout.flush()  # a pipe closed early fails here, inside the handler, not at interpreter exit
        return code
    except (UsageError, CommandFailed) as err:
        print(f"{name}: {err}", file=sys.stderr)
        return err.exit_code
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except _USER_ERRORS as err:
        print(f"{name}: {_os_message(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:
        if isinstance(err, _scan_error()):
            print(f"{name}: {err}", file=sys.stderr)
            return 2
        if _is_duckdb_error(err):  # a catalog that is empty, cut short or not a catalog at all
            first = str(err).splitlines()[0] if str(err) else type(err).__name__
            results = getattr(args, "results", "results")
            print(
                f"{name}: the history catalog under {results} cannot be read ({first}); rebuild it from the "
                f"stage tables with `borescan rebuild-catalog --results {results}`, or rerun the pipeline",
                file=sys.stderr,
            )
            return 1
        raise


def _is_duckdb_error(err: BaseException) -> bool:
    """Return whether ``err`` is a DuckDB error.

    The module is imported only by the commands that open the catalog.
    """
    duckdb = sys.modules.get("duckdb")
    return duckdb is not None and isinstance(err, duckdb.Error)


def _os_message(err: OSError) -> str:
    """``str(err)`` without Python's ``[Errno 2]`` prefix when the error names its file."""
    if err.strerror and err.filename is not None:
        return f"{err.filename}: {err.strerror}"
    return str(err)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
