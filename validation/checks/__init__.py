"""The checks: what a run measures and the statistics that judge it.

* :mod:`~validation.checks.agreement`: the full rigid body against the reduced model
  (lambda1, RMS, spectra, STCC, the amplitude scan) and the exact-twin checks;
* :mod:`~validation.checks.anchors`: the shared code's anchors (linearisation, stability);
* :mod:`~validation.checks.conformance`: the model files against the reduced model's
  specification;
* :mod:`~validation.checks.contract`: the engine contract (``cip-validate contract``);
* :mod:`~validation.checks.rod`: the coupling rod (stretch, rigidity);
* :mod:`~validation.checks.divergence`: runs that leave the small-angle regime or blow up;
* :mod:`~validation.checks.metrics`: balancing error, RMS, spectra, STCC (one function per
  estimator; the STCC's compiled loop in ``_stcc_kernel``);
* :mod:`~validation.checks.stats`: intervals, tolerances and verdict rules;
* :mod:`~validation.checks.multifidelity`: the engine's agreement estimated with its exact
  twin as control variate (two-model MFMC: estimate, interval, allocation).
"""
