"""Station configuration files: YAML read safely from files that may be hostile, the declared
schema of every section and key (``schema``, pydantic; docs/config.md is generated from it by
``docs``), the checks that give every bad key one line naming its path and what is allowed,
and the sections the data commands read (``device:``).

Holds ``safe_yaml``, ``schema``, ``docs``, ``checks`` and ``sections``.  May import only the
foundation (errors, atomic) and pydantic; everything that reads a configuration imports this,
never the other way round.
"""
