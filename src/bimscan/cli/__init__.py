"""The ``bimscan`` command line: one command per pipeline job, composed from the stages."""
