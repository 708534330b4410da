"""Exchanging cases with engines outside Python: the file protocol (:mod:`.case`).

(The chunk protocol over stdin/stdout, for engines that only step the model,
is an engine of the registry: :mod:`cip.engines.process`.)
"""
