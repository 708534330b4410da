"""Regression against a stored run: the baseline and what makes two runs comparable.

* :mod:`~validation.regression.baseline`: exact, roundoff and statistical modes;
* :mod:`~validation.regression.fingerprint`: the numerics fingerprint (CPU flags, BLAS);
* :mod:`~validation.regression.versions`: the package versions a run records.
"""
