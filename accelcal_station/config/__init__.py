"""Station configuration files: YAML read safely from files that may be hostile, the checks
that give every bad key one line naming its path and what is allowed, and the sections the
data commands read (``device:``).

Holds ``safe_yaml``, ``checks`` and ``sections``.  May import only the foundation (errors,
atomic); everything that reads a configuration imports this, never the other way round.
"""
