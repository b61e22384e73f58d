"""Station configuration files: YAML read safely from files that may be hostile, the declared
schema of every section and key (``schema``, pydantic; docs/config.md is generated from it by
``docs``), the checks that give every bad key one line naming its path and what is allowed,
and the sections the data commands read (``device:``).

Holds ``safe_yaml``, ``section`` (the base of every section), ``schema``, ``validation`` (one validation,
one line per error), ``kinds`` (the unions on
``device.driver`` and ``jig.type``), ``parts``, ``docs``, ``checks``, ``sections`` and ``event_log`` (the station's
logging: section applied).  May import only the foundation (errors, atomic, fileguard) and
pydantic; everything that reads a configuration imports this,
never the other way round.
"""
