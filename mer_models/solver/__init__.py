"""The optimiser every command depends on: the kinematic energy and its minimisation.

* :mod:`.energy` - ``f_kin = L_kp + L_cst + L_vel + L_norm`` (paper, Eq. 5-9) and its goals;
* :mod:`.ik` - per-frame damped Gauss-Newton (Levenberg-Marquardt) on that energy;
* :mod:`.optimize` - the whole-trajectory optimiser (``--method optimize``, ``--refine K``, the teacher);
* :mod:`.limits` - the joint-limit parametrisation the optimiser and the model's output share;
* :mod:`.tridiagonal` - the block-tridiagonal solve of whole windows;
* :mod:`.physics` - the physical terms (floor, joint speed, stance feet, self-penetration), as penalties
  (with :mod:`.goal_edits` and :mod:`.repair`; the default) or as constraints (:mod:`.constrained`,
  with the stance foot's no-slip term :mod:`.stance` and its self rows along faces fixed per round :mod:`.faces`);
* :mod:`.balance_term` - the balance term (``--balance``, opt-in): the ZMP in the support polygon and
  flight ballistic, rounds of whole-window iterations after the solve.
"""
