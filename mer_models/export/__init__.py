"""What a retargeted motion becomes on disk: the files a tracker or a viewer reads.

* :mod:`.writers` - :class:`~.writers.TargetMotion`, LAFAN1-style CSV, the npz of a motion tracker (mjlab, BeyondMimic), Foxglove MCAP;
  the robot in the MCAP (TF frames named after its links, its shapes, its URDF) is built by
  :mod:`mer_data.shards.foxglove`, which the MCAP shards share;
* :mod:`.mjcf` - a robot's MuJoCo model (``mer robots export``); :mod:`.geometry` - what draws a robot per body
  (its visual meshes where they can be read, else its collision shapes: :func:`~.geometry.robot_meshes`);
* :mod:`.plot` (a PNG film strip), :mod:`.video` (GIF / MP4 side by side, the robot drawn) and
  :mod:`.viewer` (``mer view``: the robot in the browser, viser; :mod:`.viewer_guard`: its websocket
  open to its own page only, SIGTERM as Ctrl-C).
"""
