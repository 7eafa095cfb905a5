"""Robots: a robot description in, a registered robot (card + URDF + :class:`~mer_data.skeleton.Skeleton`) out.

* :mod:`.urdf` (strict, safe URDF loading) and :mod:`.urdf_checks` (structural checks with file and line);
* :mod:`.mjcf` (an MJCF's tree), read by :mod:`.mjcf_xml` (includes, files confined to the model's
  folder, expansion counted) and compiled by :mod:`.mjcf_compile` (MuJoCo);
* :mod:`.mesh_io` - every mesh file read with trimesh: size-capped, never an archive;
* :mod:`.card` - the robot card (YAML beside the URDF: key points, CSV layout);
* :mod:`.builder` - URDF + card -> skeleton graph;
* :mod:`.keypoints` and :mod:`.keypoint_body` - proposing the 14 key points of an unknown robot;
* :mod:`.register` (``mer robots register``), :mod:`.registry` (name -> :class:`~.registry.Robot`),
  :mod:`.location` (where user robots live), :mod:`.table` (``mer robots show``);
* :mod:`.articulation` - the robot's own articulation as a simulator loads it, in each tracker's order;
* :mod:`.example` - the small humanoid ``mer demo`` registers;
* ``builtin/<name>/`` - the 8 built-in robots' URDFs, cards and licences (package data).

A new robot format (MJCF, ...) is read here and ends as the same card + skeleton.
"""
