"""Imported by a local sweep's forkserver at its start: the forkserver dies with the sweep.

A module of its own because importing it has that effect (see
:mod:`validation.sweeps.lifeline`); nothing else imports it.
"""

from __future__ import annotations

from validation.sweeps.lifeline import die_with_parent

die_with_parent()
