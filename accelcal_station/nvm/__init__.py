"""Safe NVM writing: the calibration blob (versioned, CRC-32 protected) and the A/B slot
writer that burns, reads back and verifies it on any board's NVM, with backups.

Holds ``blob``, ``writer`` (with ``outcome``) and ``image_file`` (the backup file).  May import
``drivers`` (the NVM interface), ``config`` and the foundation; never the station, the store or the CLI.
"""
