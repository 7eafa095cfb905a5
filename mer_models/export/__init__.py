"""What a retargeted motion becomes on disk: the files a tracker or a viewer reads.

* :mod:`.writers` - :class:`~.writers.TargetMotion`, LAFAN1-style CSV, the npz of a motion tracker (mjlab, BeyondMimic), Foxglove MCAP;
* :mod:`.foxglove_robot` - the robot in the MCAP (TF frames named after its links, its shapes, its URDF);
* :mod:`.mjcf` - a robot's MuJoCo model (``mer robots export``); :mod:`.geometry` - collision shapes per link for both;
* :mod:`.plot` (a PNG film strip) and :mod:`.video` (GIF / MP4 side by side).
"""
