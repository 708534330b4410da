"""The ``cip-validate`` commands, one module per group; each module has ``register(sub)``.

* :mod:`.analysis`: lyapunov, critical-gain, stability
* :mod:`.simulation`: simulate, linearize
* :mod:`.suite`: run, baseline
* :mod:`.sweeping`: sweep, sweep-plot
"""
