"""The ``cip-validate`` commands, one module per group; each module has ``register(sub)``.

* :mod:`.analysis`: lyapunov, critical-gain, stability
* :mod:`.simulation`: simulate, linearize
* :mod:`.suite`: run, baseline
* :mod:`.engines`: engines (every engine side by side)
* :mod:`.sweeping`: sweep, sweep-plot
"""
