"""Placeholder: `rig run`, `rig list`, `rig view` are being written."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    pass
