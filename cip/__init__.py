"""The full rigid-body CIP: the model, the engines that step it, and the running machinery.

* the model: :mod:`cip.model` (the shipped MJCF edited), :mod:`cip.names` (element
  names), :mod:`cip.mjcf_params` (a model file read into the reduced model's terms),
  :mod:`cip.conformance` (its physical content), :mod:`cip.linearize` (about upright);
* the engines: :mod:`cip.engines`, one module per family;
* running: :mod:`cip.runner` (the delayed random-gain control, a delay chunk at a time),
  :mod:`cip.simulate` and :mod:`cip.lyapunov` (the drivers), :mod:`cip.workers`
  (worker processes for engines that hold the GIL), :mod:`cip.mjtimer`,
  :mod:`cip.mjstages`, :mod:`cip.quiet`.
"""
