"""The small shared base every other room of :mod:`mer_data` (and :mod:`mer_models`) stands on.

* :mod:`.errors` - one exception hierarchy, each error naming file, line, element and fix;
* :mod:`.limits` - the size limits on untrusted input, and on what a motion reader produces;
* :mod:`.numbers` - the one strict reader of numbers in text (ASCII decimal: no ``1_0``, no Unicode digits);
* :mod:`.safe_io` - reading untrusted files (regular files only, size-capped, gunzip capped), strict
  JSON / YAML (no duplicate keys, no YAML aliases);
* :mod:`.outputs` - outputs checked before a job, the OS's refusals as one error, files mer did not
  write never replaced;
* :mod:`.atomic` - writes that are never seen half-done, never through a planted link, and a full
  disk as one error; :mod:`.locks` - one owner per output;
* :mod:`.hub_files` - downloads from a Hub server that may lie (checked, capped, hashed);
* :mod:`.finite` - the last check before anything is written: every number finite;
* :mod:`.suggest` - "did you mean ...?" for names typed by hand (robots, models).
"""
