"""Image, EXR and colour I/O: the only place where sRGB encoding happens."""
