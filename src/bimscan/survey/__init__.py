"""Stage 5: surveys: stations (from a file or planned), multi-station runs, merged clouds."""
