"""Tests of VoxNeRO (a package: helpers are imported as ``tests.<folder>.<module>``)."""
