"""Survey planning from the IFC: the fewest tripod stations that cover the chosen classes at the
asked density, joined into one registration graph (``bimscan plan``; docs/guide/planning.md).

``config`` (the settings), ``surface`` (samples on the elements), ``visibility`` (what each
candidate sees, and how densely), ``graph`` (registration), ``select`` (greedy, local search,
MILP), ``plan`` (the space, planning and checking, the figures), ``measure`` (coverage on a
scan), ``report`` (the plan folder).
"""
