"""The sub-command modules; what the commands with actions share."""
from __future__ import annotations

import argparse


def action_parser(actions: argparse._SubParsersAction, name: str, help: str, epilog: str) -> argparse.ArgumentParser:
    """An action of a sub-command (``apac-mj forced-response run``): ``help`` is also its description, and
    ``epilog`` is shown as written."""
    return actions.add_parser(name, help=help, description=help[0].upper() + help[1:] + ".", epilog=epilog,
                              formatter_class=argparse.RawDescriptionHelpFormatter)


def study_arguments(p: argparse.ArgumentParser, set_help: str) -> None:
    """A study's ``run`` action: ``--out STUDY_DIR`` (created or resumed), ``--set KEY=VALUE`` (``set_help``
    says which fields) and ``--no-progress``."""
    p.add_argument("--out", required=True, metavar="STUDY_DIR", help="the study directory (created or resumed)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help=set_help)
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
