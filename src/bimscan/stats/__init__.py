"""Stage 9: dataset statistics and technical validation (paper Figs. 4-6).

``collect`` (per-unit figures, from unit.json or streamed clouds), ``summary`` (tables and
stability), ``plots`` (PNG figures), ``report`` (CSV, JSON, PNG and Markdown files).
"""
