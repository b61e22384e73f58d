"""The library face (in progress)."""
