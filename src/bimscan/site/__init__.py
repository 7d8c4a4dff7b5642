"""Stage 3b: the scene as the site looks when scanned (construction stage, clutter, temporary works)."""
