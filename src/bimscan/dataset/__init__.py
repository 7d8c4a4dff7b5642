"""Stages 7-8: data units and datasets.

``spec`` (dataset spec files), ``build`` (the resumable builder), ``executors`` (local
processes, Ray, serial), ``manifest`` (the folder layout, manifest, checksums), ``demo`` (the
spec of ``bimscan demo``).
"""
