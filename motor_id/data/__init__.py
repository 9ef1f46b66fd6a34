"""Data in and out: CSV and bag readers with field mapping, importers, the ring buffer."""
