"""The small shared base every other room of :mod:`mer_data` (and :mod:`mer_models`) stands on.

* :mod:`.errors` - one exception hierarchy, each error naming file, line, element and fix;
* :mod:`.limits` - the size limits on untrusted input;
* :mod:`.safe_io` - reading untrusted files (regular files only, size-capped, gunzip capped);
* :mod:`.atomic` - writes that are never seen half-done; :mod:`.locks` - one owner per output;
* :mod:`.finite` - the last check before anything is written: every number finite;
* :mod:`.suggest` - "did you mean ...?" for names typed by hand (robots, models).
"""
