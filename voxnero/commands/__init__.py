"""One module per ``voxnero`` sub-command (see :mod:`voxnero.cli`)."""
