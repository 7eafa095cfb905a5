"""Motion: source-motion files in, origin-normalized windows, features and training samples out.

* readers and writers of source formats: :mod:`.lafan1` (LAFAN1 robot CSV, :class:`~.lafan1.Motion`)
  over :mod:`.csv_numeric` (strict numeric CSV); a new motion format gets a module of its own here;
* :mod:`.plausibility` (refuse the impossible, warn on the unusual) and :mod:`.resample` (to 30 Hz);
* :mod:`.features` (per-joint ``(T, J, 9)`` features), :mod:`.windows` (fixed-length windows);
* :mod:`.splits` (train / evaluation clips) and :mod:`.samples` (training samples and their batching:
  the contract between the data and the model).
"""
