"""The guards every file the station reads or writes goes through.

``regular``: an input is read only when it is a regular file (a FIFO, a device, a
/proc or /sys entry is refused before a byte is read) and no larger than the stated
limit of its kind.  ``identity``: an output is never the same file as an input or the
results store (same device and inode, or the same resolved path when the output does
not exist yet).  ``kind``: an output never replaces an SQLite database or a file of another
kind than it writes (sniffed from its head) unless forced.  ``cells``: a text cell a
spreadsheet would run is made inert before it is exported.

Foundation layer: imports only ``errors``.
"""
