"""Parameter studies: the public names of :mod:`validation.sweeps` in one place.

The implementation lives in :mod:`validation.sweeps` (study schema, parameter
mapping, metric evaluation, storage, schedulers, plots); this module keeps
``from validation.sweep import Study, run_sweep, ...`` working.  It re-exports
exactly the package's ``__all__``, so the two lists cannot drift apart.
"""

from validation import sweeps as _package
from validation.sweeps import *  # noqa: F403

__all__ = _package.__all__
