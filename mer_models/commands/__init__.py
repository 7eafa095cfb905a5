"""Thin command-line parsers of the model commands (``mer train``, ``mer retarget``, ``mer evaluate``)."""
