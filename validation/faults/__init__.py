"""Fault catalogues: wrong physics injected on purpose, which the checks must flag.

* :mod:`~validation.faults.catalogue`: faults at the engine boundary (the model copy,
  the controls the engine receives, its parameters);
* :mod:`~validation.faults.file`: faults written into a model file;
* :mod:`~validation.faults.shared`: faults in the shared code (linearisation, gains);
* :mod:`~validation.faults.selftest`: ``cip-validate selftest``, every fault through the
  checks, with the smallest flagged size;
* :mod:`~validation.faults.selftest_paths`: which check is expected to flag which fault.
"""
