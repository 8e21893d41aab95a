"""``apac-mj``: one command line for the whole project.

Each sub-command lives in its own module, which exposes
``register(subparsers)``; this file only wires them together.
"""
from __future__ import annotations

import argparse
import errno
import importlib
import os
import signal
import sys

from apac_mj.util.memory import address_space_limit, check_address_space, is_out_of_memory, out_of_memory

#: (module, description) for every sub-command module; each registers its own parsers.
COMMAND_MODULES = [
    "apac_mj.commands.tasks",
    "apac_mj.commands.grid",
    "apac_mj.commands.report",
    "apac_mj.commands.demo",
    "apac_mj.commands.check_kinematics",
    "apac_mj.commands.train",
    "apac_mj.commands.evaluate",
    "apac_mj.commands.record",
    "apac_mj.commands.screenshot",
    "apac_mj.commands.forced_response",
    "apac_mj.commands.zoo",
    "apac_mj.commands.adaptation",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="apac-mj",
        description="Arbitrated Predictive Actor-Critic (Fard & Trappenberg) on a MuJoCo two-link arm.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM (what ``kill PID`` and schedulers send): handled as Ctrl-C is, so the same cleanup runs and the
    same message says what was saved and how to resume."""


def on_sigterm(signum: int, frame: object) -> None:
    raise Terminated()


def install_signal_handlers() -> object:
    """SIGTERM raises :class:`Terminated` (a KeyboardInterrupt) in the main thread; returns the handler it
    replaced (None: not the main thread, nothing installed)."""
    try:
        return signal.signal(signal.SIGTERM, on_sigterm)
    except ValueError:  # not the main thread (main() called from a thread)
        return None


#: What a failed file-system call means and what to do, by errno.
_OS_ERRORS = {
    errno.ENOSPC: "no space left on the device of {file}; free some space (or use another --out), then run the "
                  "same command again: what was written is intact, and a run resumes from its last checkpoint",
    errno.EDQUOT: "disk quota exceeded writing {file}; free some space (or use another --out), then run the same "
                  "command again: what was written is intact, and a run resumes from its last checkpoint",
    errno.EROFS: "{file} is on a read-only file system; use an --out on a writable one",
    errno.EACCES: "permission denied for {file}; use another --out, or make it writable for this user",
    errno.EPERM: "operation not permitted on {file}; use another --out, or make it writable for this user",
}


def os_error_message(e: OSError) -> str:
    """An OSError as one line naming the file and the way out."""
    file = e.filename if e.filename is not None else "a file"
    if e.errno in _OS_ERRORS:
        return _OS_ERRORS[e.errno].format(file=file) + f" ({e.strerror})"
    if isinstance(e, FileNotFoundError) and e.filename is None:
        return str(e)  # this project's own "does not exist" messages
    return f"{e.strerror or e}: {file}" if e.filename is not None else str(e)


#: Exit status when the reader of stdout goes away (``apac-mj tasks | head -2``): 128 + SIGPIPE, what a shell
#: reports for a command SIGPIPE ended (``yes | head``), so that ``set -o pipefail`` still sees the output cut.
EXIT_BROKEN_PIPE = 128 + 13


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status. A reader of stdout that goes away ends it quietly (no message, no
    traceback) with :data:`EXIT_BROKEN_PIPE`."""
    try:
        try:
            return _main(argv)
        finally:
            sys.stdout.flush()  # here, not at exit, where a closed pipe would print "Exception ignored"
    except BrokenPipeError:
        _stdout_to_devnull()
        return EXIT_BROKEN_PIPE


def _stdout_to_devnull() -> None:
    """Point stdout's file descriptor at /dev/null: what is still buffered is dropped at exit without an error
    (the way the Python docs give for SIGPIPE)."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):  # no file descriptor (stdout replaced, e.g. captured): nothing to redirect
        pass


def command_line(args: argparse.Namespace) -> str:
    """The command for messages: its name and the directory or file it writes or reads (``apac-mj train --out
    runs/x``)."""
    for flag, name in (("--out ", "out"), ("", "run_dir"), ("--run ", "run")):
        if getattr(args, name, None) is not None:
            return f"apac-mj {args.command} {flag}{getattr(args, name)}"
    return f"apac-mj {args.command}"


def error_message(e: BaseException, args: argparse.Namespace) -> str | None:
    """An error that ends a command as one line: out of memory said as such (:mod:`apac_mj.util.memory`; an
    ImportError too when the address space is limited, where a library that cannot map itself names another
    cause, e.g. dm_control's "Cannot initialize a headless EGL display"), an OSError naming its file, else the
    error's own message; None for any other ImportError."""
    if is_out_of_memory(e) or (isinstance(e, ImportError) and address_space_limit() is not None):
        return out_of_memory(e, command_line(args))
    if isinstance(e, ImportError):
        return None
    if isinstance(e, OSError):
        return os_error_message(e)
    return e.args[0] if isinstance(e, KeyError) and e.args else str(e)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:  # bare `apac-mj`: what it can do
        parser.print_help()
        return 0
    previous = install_signal_handlers()
    try:
        check_address_space(args.command, command_line(args))
        return int(args.func(args) or 0)
    except KeyboardInterrupt as e:
        terminated = isinstance(e, Terminated)
        print("terminated (SIGTERM)" if terminated else "interrupted", file=sys.stderr)
        return 128 + (signal.SIGTERM if terminated else signal.SIGINT)
    except BrokenPipeError:
        raise  # the reader of stdout went away: main() ends quietly
    except (MemoryError, ImportError, OSError, KeyError, ValueError, RuntimeError) as e:
        message = error_message(e, args)
        if message is None:
            raise  # an ImportError that is not for lack of memory: its traceback names the module
        print(f"apac-mj {args.command}: error: {message}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
