"""Kinematics of one skeleton: forward kinematics, rotations, joint maps and body-part scaling.

* :mod:`.fk` (batched, differentiable FK) and :mod:`.fk_kernel` (its compiled kernel);
* :mod:`.rotations` - rotation conversions in torch;
* :mod:`.jointmap` - the joint map ``eta`` between two skeletons' key points;
* :mod:`.scaling` - a source motion's key points scaled to a target skeleton (the goals), and
  :mod:`.orientation` - the orientation goals of the oriented key points;
* :mod:`.support` - the support polygon: collision vertices near the floor, its hull, single and
  double support (the balance metric's and the balance term's).
"""
