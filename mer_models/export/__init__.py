"""What a retargeted motion becomes on disk: the files a tracker or a viewer reads.

* :mod:`.writers` - :class:`~.writers.TargetMotion`, LAFAN1-style CSV, BeyondMimic/mjlab npz, Foxglove MCAP;
* :mod:`.plot` (a PNG film strip) and :mod:`.video` (GIF / MP4 side by side).
"""
