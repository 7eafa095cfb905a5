"""Retargeting a motion, a dataset, and measuring it.

* :mod:`.inference` - a batch of independent windows, sampled or optimised;
* :mod:`.long_horizon` - any length, in model-sized windows;
* :mod:`.clip` - one motion (file or arrays) to one or many targets (``mer retarget IN``);
* :mod:`.dataset` - every clip of a folder or Hub dataset to every target (``mer retarget --input``),
  in worker processes (:mod:`.workers`, ``--workers N``);
* :mod:`.metrics` and :mod:`.evaluate` (``mer evaluate``) - the paper's metrics; :mod:`.artifacts` - what a
  tracker trips over; :mod:`.feasible` - the feasibility pass after a physics solve.
"""
