"""``apac-mj``: one command line for the whole project.

Each sub-command lives in its own module, which exposes
``register(subparsers)``; this file only wires them together.
"""
from __future__ import annotations

import argparse
import importlib
import sys

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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:  # bare `apac-mj`: what it can do
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (KeyError, ValueError, FileNotFoundError, RuntimeError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        print(f"apac-mj {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
