"""The shipped track specs. This directory installs as the package `d2a_tracks` (see setup.py),
so `d2a make-track straightaway` finds them in a wheel as well as in a source checkout."""
