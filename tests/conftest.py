"""Fixtures shared across test modules."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def smoke_run_once(tmp_path_factory):
    """One ``cip-validate run --profile smoke`` (figures included) for the whole session:
    (exit status, output directory).  Read it only; copy what a test changes."""
    from validation.cli import main

    out = tmp_path_factory.mktemp("smoke")
    return main(["run", "--profile", "smoke", "--out", str(out)]), out
