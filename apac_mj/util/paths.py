"""Where the shipped data lives: the MJCF model (assets/) and task files (tasks/).

In a source checkout these are the top-level ``assets/`` and ``tasks/``
folders; in an installed wheel they are the packages ``apac_mj.assets`` and
``apac_mj.tasks`` (the same files, mapped by pyproject.toml).
"""
from __future__ import annotations

import importlib.resources
from pathlib import Path

_REPO = Path(__file__).resolve().parents[2]


def _data_dir(name: str) -> Path:
    # A source checkout has pyproject.toml next to the folder; an installed
    # package's parent is site-packages, where an unrelated top-level
    # "assets"/"tasks" folder must not be mistaken for ours.
    local = _REPO / name
    if (_REPO / "pyproject.toml").is_file() and local.is_dir():
        return local
    return Path(str(importlib.resources.files(f"apac_mj.{name}")))


def assets_dir() -> Path:
    return _data_dir("assets")


def tasks_dir() -> Path:
    return _data_dir("tasks")


def arm_xml_path() -> Path:
    return assets_dir() / "planar_arm.xml"


def repo_root() -> Path:
    """The source checkout's top folder (docs/ lives there; an installed wheel has no docs/)."""
    return _REPO
