"""Global illumination shared by every method's shading: DDGI light probes (:mod:`.ddgi`)."""
