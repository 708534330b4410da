"""The rigid-body engines: one module per engine family, each a registry entry.

* :mod:`~cip.engines.rigid_body`: :class:`~cip.engines.rigid_body.RigidBodyEngine`, the
  adapter every rigid-body engine shares, and MuJoCo on the CPU;
* :mod:`~cip.engines.mjx`: MJX (JAX);
* :mod:`~cip.engines.warp`, :mod:`~cip.engines.warp_batch`: MuJoCo Warp;
* :mod:`~cip.engines.drake`, :mod:`~cip.engines.drake_plant`: Drake;
* :mod:`~cip.engines.bullet`, :mod:`~cip.engines.exudyn`, :mod:`~cip.engines.simbody`;
* :mod:`~cip.engines.pinocchio`: Pinocchio (ABA, semi-implicit Euler, a rigid rod; judged by
  time-step refinement);
* :mod:`~cip.engines.dart`: DART (semi-implicit Euler, a rigid rod; judged by time-step
  refinement);
* :mod:`~cip.engines.physx`: PhysX through SAPIEN (CPU, float32; semi-implicit Euler, a rigid
  rod; judged by time-step refinement);
* :mod:`~cip.engines.newton`: Newton's Featherstone solver on warp (float32, a rigid rod by
  cipval's projection; judged by time-step refinement);
* :mod:`~cip.engines.genesis`: Genesis (its rigid solver on the CPU, semi-implicit Euler,
  a rigid rod by cipval's projection; judged by time-step refinement);
* :mod:`~cip.engines.rollout`: :class:`~cip.engines.rollout.ModelRollout`, the half of a
  rollout backend every engine built from the compiled model shares;
* :mod:`~cip.engines.process`: an engine in another program (the chunk protocol).

A new engine is one module here, one entry in :data:`cipcore.registry.ENGINES` and
one extra in ``pyproject.toml``.
"""
